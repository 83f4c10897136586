"""Does the FCN still mark a same-colour look-alike up close? The camera (the controller's own pose family)
is aimed straight at each same-colour distractor of a scene from several heights, and on the views without
the target the script counts how often the FCN marks something, and how often mostly that distractor, by
the distractor's size in the image. Tells whether "approach to verify" can undo a false sighting.

    python baselines/fcn_lookalike_views.py --scenes 60
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from tqdm import tqdm

from mani_active_vision.agents.fcn import load_pretrained
from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.evaluation.rollout_frames import RELATIONS, object_map, slot_relations
from mani_active_vision.evaluation.views import aimed_views

SIZE_BINS = (1, 100, 400, 1600, 5000, 10**9)
"""edges of the distractor's size in pixels"""


@dataclass
class Args:
    scenes: int = 60
    """scenes (resets), seeds from `seed`"""
    seed: int = 500_000
    """first scene seed (held out)"""
    heights: tuple[float, ...] = (0.15, 0.25, 0.4, 0.6, 0.9)
    """camera heights (m) to look at each distractor from"""
    object_set: str = "unseen"
    image_size: int = 128
    weights: str | None = None
    """FCN checkpoint (default: the shipped agents/weights/fcn.pt)"""


def main(args: Args):
    torch.set_num_threads(1)
    model = load_pretrained(args.weights)
    config = EnvConfig(start_pose="search", object_set=args.object_set, image_size=args.image_size)
    env = gym.make(ENV_ID, **config.task_kwargs())
    base, rows = env.unwrapped, []  # (distractor pixels, anything marked, mostly on it)
    try:
        for seed in tqdm(range(args.seed, args.seed + args.scenes), desc="scenes"):
            obs, _ = env.reset(seed=seed)
            relations = slot_relations(base.object_names[0], base.object_colors[0])
            for k in np.flatnonzero(relations == RELATIONS.index("same colour")):
                for images in aimed_views(base, k, args.heights):
                    segmentation = images["segmentation"][0, ..., 0].numpy()
                    if (segmentation == int(base.target_seg_id[0])).any():
                        continue
                    on_distractor = object_map(base, segmentation) == k + 1
                    pred = model.predict(images["rgb"], obs["extra"]["target_image"], largest_component=True)[0].numpy()
                    rows.append(
                        (on_distractor.sum(), pred.any(), (pred & on_distractor).sum() > 0.5 * max(pred.sum(), 1))
                    )
    finally:
        env.close()
    rows = np.array(rows, dtype=float)
    print(
        f"\n{len(rows)} views aimed at a same-colour distractor, target not in view ({args.object_set} objects, "
        f"{args.image_size}²)\n"
    )
    print("| distractor size (px) | views | FP rate | FP mostly on the distractor |")
    print("|---|---|---|---|")
    for lo, hi in zip(SIZE_BINS[:-1], SIZE_BINS[1:]):
        sel = (rows[:, 0] >= lo) & (rows[:, 0] < hi)
        if sel.any():
            print(
                f"| {lo}–{hi if hi < 10**9 else '…'} | {int(sel.sum())} | {rows[sel, 1].mean():.2f} | {rows[sel, 2].mean():.2f} |"
            )


if __name__ == "__main__":
    main(tyro.cli(Args))
