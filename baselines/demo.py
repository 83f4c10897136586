"""The main job: train the DQN (with the scripted exploration) in ActiveVisionFind-v0, evaluate it,
draw its learning curves and record it.

Trains `agents.dqn` (the paper's schedule: 100 episodes, ε 0.1 -> 0.02; by default the `hold_stay_fine`
preset: the shaped learner's reward, without which it does not learn in 100 episodes, paying for time well
inside success, the scripted servo acting the first 10 episodes, 128 hidden units, a seventh action `stay`
and the mask's share and centroid in the state, the learning rate decayed to 1e-4, half steps near success as
deployed; docs/control.md §7, §9, §12) on the
ground-truth box (privileged training: learning on the FCN's box, whose false positives jump between
look-alike objects, failed), then evaluates the greedy agent (exploration, then the DQN) on fixed
evaluation seeds (unseen objects) acting on the box from the shipped FCN at 128² (`envs.FCN_IMAGE_SIZE`), held
through its misses (`envs.FCN_BOX_HOLD_STEPS`), segmenting the camera's frame at its own 128²
(`envs.FCN_SEGMENT_SIZE`), with half steps close to the target (`envs.DQN_FINE_STEP_SIZE`,
`envs.DQN_FINE_NEAR_CENTRE`, `envs.DQN_FINE_FROM_AREA`), a step back when too close (`envs.DQN_BACK_WHEN_CLOSE`),
`stay` only in success and the held box moving with the camera — as deployed,
`EnvConfig.as_dqn_deployed` — and on the ground-truth box,
records the first FCN episodes to a Rerun file, prints the tables and where everything was written. It then
evaluates the shipped agent (`agents/weights/dqn.pt`, scripts/make_dqn.sh) as deployed, on the FCN's box and
unseen objects, on the same episode seeds.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import torch

from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.agents.q_network import checkpoint_env_config
from mani_active_vision.envs import DQN_FINE_STEP_SIZE, EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_preset_env
from mani_active_vision.evaluation.protocol import eval_seeds, evaluate
from mani_active_vision.evaluation.report import markdown_table, plot_curves
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import summarize
from mani_active_vision.recording import RerunRecorder


@dataclass
class Args:
    env: EnvConfig = field(default_factory=lambda: dqn.PRESETS["hold_stay_fine"][1].env)
    """the env the DQN learns in (default: the preset's; its box_source is the training box: ground_truth)"""
    seed: int = 0
    """training seed (0: the shipped agent's, scripts/make_dqn.sh)"""
    preset: str = "hold_stay_fine"
    """the DQN's configuration (agents.dqn.PRESETS): hold_stay_fine, hold_stay_decay, hold_stay, hold_demo_wide,
    hold_demo, shaped_demo, hold, shaped, paper"""
    episodes: int = 100
    """training episodes (paper: 100)"""
    eval_episodes: int = 10
    """greedy evaluation episodes (seeds from 1,000,000)"""
    eval_object_set: str = "unseen"
    """the objects of the evaluation and recorded episodes (training uses env.object_set: train)"""
    eval_fine_step_size: float = DQN_FINE_STEP_SIZE
    """the evaluation env's fine moves, which the DQN takes near the target (0: none; a network trained on the full
    step takes them too)"""
    box_source: str = "fcn"
    """the box the agent acts on when evaluated and recorded: fcn (the shipped one-shot segmentation network,
    as in the paper) or ground_truth; the other one is evaluated too"""
    out_dir: str = "outputs/demo"
    """where the checkpoint, curves and metrics go"""
    record_episodes: int = 2
    """evaluation episodes (the first ones) to record to a Rerun file (0: none)"""
    recording: str = "recordings/demo.rrd"
    """the Rerun file of the recorded episodes"""
    shipped: str = "agents/weights/dqn.pt"
    """the shipped DQN, evaluated as deployed (its checkpoint's env: the FCN's box, unseen objects); empty: skip"""


def eval_env(args: Args, box_source: str) -> EnvConfig:
    """The evaluation env on `box_source`, as the shipped DQN is deployed: the training env with the evaluation
    objects and the fine moves near the target (`eval_fine_step_size`), and on the FCN's box
    `EnvConfig.as_dqn_deployed`: the box held through the FCN's misses, its verifier bars, the network segmenting
    the camera's own 128², the fine moves only close to the image centre, the held box moving with the camera."""
    config = args.env.replace(box_source=box_source, object_set=args.eval_object_set)
    if box_source == "fcn":
        config = config.as_dqn_deployed()
    return config.replace(fine_step_size=args.eval_fine_step_size)


def main(args: Args):
    torch.set_num_threads(1)
    if args.preset not in dqn.PRESETS:
        raise ValueError(f"preset={args.preset!r} is not one of: {', '.join(dqn.PRESETS)}")
    if args.box_source not in ("fcn", "ground_truth"):
        raise ValueError(f"box_source={args.box_source!r} is not one of: fcn, ground_truth")
    train_args = dataclasses.replace(
        dqn.PRESETS[args.preset][1],
        env=args.env,
        seed=args.seed,
        episodes=args.episodes,
        explore=True,
        run_dir=args.out_dir,
        run_name="dqn",
    )
    print(
        f"training DQN ({args.episodes} episodes, {args.preset} configuration, scripted exploration, "
        f"{args.env.box_source} box)"
    )
    result = dqn.train(train_args)
    history = result["history"]
    curves = {key: os.path.join(args.out_dir, f"learning_curve_{key}.png") for key in ("return", "success")}
    for key, path in curves.items():
        plot_curves({"DQN + exploration": [[h[key] for h in history]]}, path, key, title="training")

    evaluations, metrics = {}, os.path.join(args.out_dir, "evaluation.json")
    other = "ground_truth" if args.box_source == "fcn" else "fcn"
    runs = [(f"explore→dqn, {b} box", eval_env(args, b), result["checkpoint"]) for b in (args.box_source, other)]
    if args.shipped:
        env = checkpoint_env_config(args.shipped)
        runs.append((f"shipped {args.shipped}, {env.box_source} box, {env.object_set} objects", env, args.shipped))
    for name, config, checkpoint in runs:
        env = make_env(config)
        try:
            policy = make_policy("explore", env, then="dqn", checkpoint=checkpoint, seed=args.seed)
            episodes = evaluate(env, policy, eval_seeds(args.eval_episodes), desc=f"evaluate {name}")
        finally:
            env.close()
        evaluations[name] = {"summary": summarize(episodes), "episodes": episodes}
    save_json(evaluations, metrics)
    print(markdown_table({name: evaluation["summary"] for name, evaluation in evaluations.items()}))

    if args.record_episodes:
        recorded = eval_env(args, args.box_source)
        with RerunRecorder(make_env(recorded), args.recording) as env:
            policy = make_policy("explore", env, then="dqn", checkpoint=result["checkpoint"], seed=args.seed)
            evaluate(env, policy, eval_seeds(args.record_episodes), with_reference=False, desc="record")
    print("outputs:")
    outputs = [
        ("checkpoint", result["checkpoint"]),
        ("training history", os.path.join(result["run_dir"], "history.json")),
        ("learning curve (return)", curves["return"]),
        ("learning curve (success)", curves["success"]),
        ("evaluation metrics", metrics),
    ]
    if args.record_episodes:
        outputs.append(("recording (Rerun)", args.recording))
    for what, path in outputs:
        print(f"  {what:26s} {path}")
    if args.record_episodes:
        print(f"open the recording with: .venv/bin/rerun {args.recording}")


if __name__ == "__main__":
    main(cli_with_preset_env(Args))
