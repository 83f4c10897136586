"""Learners and policies (installed as `mani_active_vision.agents`): FCN, DQN, exploration, baselines."""
