"""The main job: train the paper's DQN (with the scripted exploration) in ActiveVisionFind-v0, evaluate it,
and draw its learning curve.

Trains `agents.dqn` with the paper's configuration (100 episodes, ε 0.1 -> 0.02, 20 hidden units) on the
box state (ground truth; `--box-source fcn` once the FCN is in), evaluates the greedy agent (exploration,
then the DQN) on fixed evaluation seeds, prints a table and where everything was written.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.agents import dqn
from mani_active_vision.agents.evaluation import evaluate, make_box_env, markdown_table, plot_curves, save_json, summarize
from mani_active_vision.agents.policies import make_policy


@dataclass
class Args:
    seed: int = 0
    """training seed"""
    episodes: int = 100
    """training episodes (paper: 100)"""
    eval_episodes: int = 10
    """greedy evaluation episodes (seeds from 1,000,000)"""
    box_source: str = "ground_truth"
    """ground_truth or fcn"""
    image_size: int = 64
    """wrist camera side in pixels"""
    out_dir: str = "outputs/demo"
    """where the checkpoint, curves and metrics go"""


def main(args: Args):
    torch.set_num_threads(1)
    train_args = dqn.Args(seed=args.seed, episodes=args.episodes, box_source=args.box_source, image_size=args.image_size,
                          explore=True, run_dir=args.out_dir, run_name="dqn")
    print(f"training DQN ({args.episodes} episodes, paper configuration, scripted exploration, {args.box_source} box)")
    result = dqn.train(train_args)
    history = result["history"]
    curve = os.path.join(args.out_dir, "learning_curve_success.png")
    plot_curves({"DQN + exploration": [[h["success"] for h in history]]}, curve, "success rate", title="training")

    env = make_box_env(**dqn.env_kwargs(train_args))
    policy = make_policy("explore", env, then="dqn", checkpoint=result["checkpoint"], seed=args.seed)
    episodes = evaluate(env, policy, range(1_000_000, 1_000_000 + args.eval_episodes), desc="evaluate")
    env.close()
    summary = summarize(episodes)
    metrics = os.path.join(args.out_dir, "evaluation.json")
    save_json({"summary": summary, "episodes": episodes}, metrics)

    print(markdown_table({"explore→dqn": summary}))
    print("outputs:")
    for what, path in [("checkpoint", result["checkpoint"]), ("training history", os.path.join(result["run_dir"], "history.json")),
                       ("learning curve (return)", os.path.join(result["run_dir"], "learning_curve.png")),
                       ("learning curve (success)", curve), ("evaluation metrics", metrics)]:
        print(f"  {what:26s} {path}")


if __name__ == "__main__":
    main(tyro.cli(Args))
