"""The main job: train the paper's DQN (with the scripted exploration) in ActiveVisionFind-v0, evaluate it,
draw its learning curve and record it.

Trains `agents.dqn` (the paper's network and schedule: 100 episodes, ε 0.1 -> 0.02, 20 hidden units;
by default with the `shaped` learner's reward, without which it does not learn in 100 episodes) on the
box state from the shipped FCN (`--box-source ground_truth` for the segmentation's box), evaluates the
greedy agent (exploration, then the DQN) on fixed evaluation seeds, records the first evaluation episodes
to a Rerun file, prints a table and where everything was written.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.agents import dqn
from mani_active_vision.agents.evaluation import evaluate, make_box_env, markdown_table, plot_curves, save_json, summarize
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.recording import record_rollouts


@dataclass
class Args:
    seed: int = 0
    """training seed"""
    preset: str = "shaped"
    """the DQN's configuration: shaped (the paper's network and schedule with a shaped reward) or paper"""
    episodes: int = 100
    """training episodes (paper: 100)"""
    eval_episodes: int = 10
    """greedy evaluation episodes (seeds from 1,000,000)"""
    box_source: str = "fcn"
    """fcn (the shipped one-shot segmentation network, as in the paper) or ground_truth"""
    image_size: int = 64
    """wrist camera side in pixels"""
    out_dir: str = "outputs/demo"
    """where the checkpoint, curves and metrics go"""
    record_episodes: int = 2
    """evaluation episodes (the first ones) to record to a Rerun file (0: none)"""
    recording: str = "recordings/demo.rrd"
    """the Rerun file of the recorded episodes"""


def main(args: Args):
    torch.set_num_threads(1)
    if args.preset not in dqn.PRESETS:
        raise ValueError(f"preset={args.preset!r} is not one of: {', '.join(dqn.PRESETS)}")
    train_args = dataclasses.replace(dqn.PRESETS[args.preset][1], seed=args.seed, episodes=args.episodes, box_source=args.box_source,
                                     image_size=args.image_size, explore=True, run_dir=args.out_dir, run_name="dqn")
    print(f"training DQN ({args.episodes} episodes, {args.preset} configuration, scripted exploration, {args.box_source} box)")
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

    if args.record_episodes:
        env = make_box_env(**dqn.env_kwargs(train_args), record_to=args.recording)
        policy = make_policy("explore", env, then="dqn", checkpoint=result["checkpoint"], seed=args.seed)
        try:
            record_rollouts(env, policy, args.record_episodes, seed=1_000_000)
        finally:
            env.close()  # writes the file's footer
    print("outputs:")
    outputs = [("checkpoint", result["checkpoint"]), ("training history", os.path.join(result["run_dir"], "history.json")),
               ("learning curve (return)", os.path.join(result["run_dir"], "learning_curve.png")),
               ("learning curve (success)", curve), ("evaluation metrics", metrics)]
    if args.record_episodes:
        outputs.append(("recording (Rerun)", args.recording))
    for what, path in outputs:
        print(f"  {what:26s} {path}")
    if args.record_episodes:
        print(f"open the recording with: .venv/bin/rerun {args.recording}")


if __name__ == "__main__":
    main(tyro.cli(Args))
