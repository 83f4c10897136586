"""The main job: train the DQN (with the scripted exploration) in ActiveVisionFind-v0, evaluate it,
draw its learning curve and record it.

Trains `agents.dqn` (the paper's network and schedule: 100 episodes, ε 0.1 -> 0.02, 20 hidden units; by
default with the `shaped` learner's reward, without which it does not learn in 100 episodes) on the
ground-truth box (privileged training: learning on the FCN's box, whose false positives jump between
look-alike objects, failed), then evaluates the greedy agent (exploration, then the DQN) on fixed
evaluation seeds acting on the box from the shipped FCN — as deployed — and on the ground-truth box,
records the first FCN episodes to a Rerun file, prints the tables and where everything was written.
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
    train_box_source: str = "ground_truth"
    """the box the DQN learns from: ground_truth (the segmentation's) or fcn"""
    box_source: str = "fcn"
    """the box the agent acts on when evaluated and recorded: fcn (the shipped one-shot segmentation network,
    as in the paper) or ground_truth; the other one is evaluated too"""
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
    train_args = dataclasses.replace(dqn.PRESETS[args.preset][1], seed=args.seed, episodes=args.episodes, box_source=args.train_box_source,
                                     image_size=args.image_size, explore=True, run_dir=args.out_dir, run_name="dqn")
    print(f"training DQN ({args.episodes} episodes, {args.preset} configuration, scripted exploration, {args.train_box_source} box)")
    result = dqn.train(train_args)
    history = result["history"]
    curve = os.path.join(args.out_dir, "learning_curve_success.png")
    plot_curves({"DQN + exploration": [[h["success"] for h in history]]}, curve, "success rate", title="training")

    evaluations, metrics = {}, os.path.join(args.out_dir, "evaluation.json")
    other = "ground_truth" if args.box_source == "fcn" else "fcn"
    for box_source in (args.box_source, other):
        env = make_box_env(**{**dqn.env_kwargs(train_args), "box_source": box_source})
        policy = make_policy("explore", env, then="dqn", checkpoint=result["checkpoint"], seed=args.seed)
        episodes = evaluate(env, policy, range(1_000_000, 1_000_000 + args.eval_episodes), desc=f"evaluate ({box_source} box)")
        env.close()
        evaluations[f"explore→dqn, {box_source} box"] = {"summary": summarize(episodes), "episodes": episodes}
    save_json(evaluations, metrics)
    print(markdown_table({name: evaluation["summary"] for name, evaluation in evaluations.items()}))

    if args.record_episodes:
        env = make_box_env(**{**dqn.env_kwargs(train_args), "box_source": args.box_source}, record_to=args.recording)
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
