"""One training run of an experiment: train a DQN, then evaluate its greedy policy on the fixed evaluation
seeds. A `sweep.Run` calls it for each condition and seed (baselines/fig5.py; the control experiments)."""

from __future__ import annotations

import dataclasses
import os

from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.envs import make_env
from mani_active_vision.evaluation.protocol import eval_seeds, evaluate
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import summarize


def train_and_evaluate(run_dir: str, train_args: dqn.Args, eval_episodes: int, progress: bool = True) -> None:
    """Train `train_args` into `run_dir` (history.json, q_network.pt), evaluate the greedy agent (after the
    scripted exploration when it trained with it) on `eval_episodes` evaluation seeds, and write, last,
    `run_dir/eval.json` (the marker of a finished run): {"summary", "episodes"}."""
    train_args = dataclasses.replace(train_args, run_dir=os.path.dirname(run_dir), run_name=os.path.basename(run_dir))
    result = dqn.train(train_args, progress=progress)
    env = make_env(train_args.env)
    try:
        checkpoint = result["checkpoint"]
        if train_args.explore:
            policy = make_policy("explore", env, then="dqn", checkpoint=checkpoint)
        else:
            policy = make_policy("dqn", env, checkpoint=checkpoint)
        label = os.path.join(os.path.basename(train_args.run_dir), train_args.run_name)
        episodes = evaluate(
            env, policy, eval_seeds(eval_episodes), with_reference=False, desc=f"eval {label}", progress=progress
        )
    finally:
        env.close()
    save_json({"summary": summarize(episodes), "episodes": episodes}, os.path.join(run_dir, "eval.json"))
