"""How long agents keep the target in focus: the share of held-out episodes in success at each step, mean ± std
over training seeds, one curve per agent (the scripted exploration, then each seed's DQN), on the FCN's box as
deployed (or the ground truth's). A curve that rises and stays up is an agent that finds the target and holds it;
one that sags is an agent that reaches success and leaves it.

    python baselines/focus_curve.py --agents hold_demo_wide=runs/seeds/stats/hold_demo_wide_avoid \\
        hold_stay=runs/seeds/stats/hold_stay --out docs/figures/focus_curve.png
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass

import numpy as np
import torch
import tyro
from tqdm import tqdm

from mani_active_vision.agents.policies import make_policy
from mani_active_vision.agents.q_network import checkpoint_env_config
from mani_active_vision.envs import make_env
from mani_active_vision.evaluation.protocol import EVAL_SEED, eval_seeds
from mani_active_vision.evaluation.report import plot_curves
from mani_active_vision.evaluation.rollout import run_episode
from mani_active_vision.json_io import save_json


@dataclass
class Args:
    agents: list[str]
    """label=folder pairs: each folder holds seed*/q_network.pt (seeds.py's runs of one preset)"""
    episodes: int = 50
    """held-out episodes per seed (seeds from `seed`)"""
    seed: int = EVAL_SEED
    box_source: str = "fcn"
    """fcn: the FCN's box as deployed (128², held through its misses); ground_truth: the checkpoint's own env"""
    out: str = "outputs/focus_curve.png"
    """the plot; the curves go beside it as JSON"""


def in_success(checkpoint: str, args: Args) -> list[float]:
    """The share of the episodes in success after each step (1, 2, ...) of one seed's agent."""
    config = checkpoint_env_config(checkpoint).replace(object_set="unseen")
    env = make_env(config.on_fcn_box() if args.box_source == "fcn" else config.replace(box_source="ground_truth"))
    try:
        policy = make_policy("explore", env, then="dqn", checkpoint=checkpoint)
        flags = [run_episode(env, policy, seed).success[1:] for seed in eval_seeds(args.episodes, args.seed)]
    finally:
        env.close()
    return np.mean(np.array(flags, float), axis=0).tolist()  # episodes all run to the step limit


def main(args: Args) -> dict:
    if args.box_source not in ("fcn", "ground_truth"):
        raise ValueError(f"box_source={args.box_source!r} is not one of: fcn, ground_truth")
    if not all("=" in item for item in args.agents):
        raise ValueError(f"--agents {args.agents}: each must be label=folder")
    agents = dict(item.partition("=")[::2] for item in args.agents)
    checkpoints = {
        label: sorted(glob.glob(os.path.join(folder, "seed*", "q_network.pt"))) for label, folder in agents.items()
    }
    for label, found in checkpoints.items():
        if not found:
            raise FileNotFoundError(f"{label}: no seed*/q_network.pt under {agents[label]!r}")
    torch.set_num_threads(1)
    total = sum(len(found) for found in checkpoints.values())
    with tqdm(total=total, desc="agents") as bar:
        curves = {}
        for label, found in checkpoints.items():
            curves[label] = []
            for checkpoint in found:
                curves[label].append(in_success(checkpoint, args))
                bar.update()
    box = "FCN's box as deployed" if args.box_source == "fcn" else "ground-truth box"
    title = f"in focus on the {box}\n{args.episodes} held-out episodes per seed, unseen objects"
    plot_curves(curves, args.out, "share of episodes in success", window=1, title=title, xlabel="step")
    save_json({"args": vars(args), "curves": curves}, os.path.splitext(args.out)[0] + ".json")
    print(f"plot: {args.out}")
    return curves


if __name__ == "__main__":
    main(tyro.cli(Args))
