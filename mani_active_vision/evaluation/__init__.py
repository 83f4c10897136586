"""Evaluation, split by job: `rollout` (the one episode loop), `reference` (the privileged servo behind
SPL), `protocol` (fixed seeds, metrics per episode), `perturbation` (push the arm away after focus),
`report` (tables, plots), `cli` (a checkpoint's env config as the command line's default),
`training_run` (one DQN run and its evaluation, for sweeps), `rollout_frames` (frames from the policies'
rollouts, to judge vision by) and `views` (the privileged view planner behind the success and hold
ceilings). The metrics themselves are `mani_active_vision.metrics`; JSON is `mani_active_vision.json_io`."""
