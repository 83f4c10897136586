"""Is the target identifiable from its picture? The camera (the controller's own pose family) is aimed at the
target and at each same-colour distractor of a scene from several heights; each object's silhouette in the
wrist view is compared with the target image's (both cropped to their box, padded square, 32²) by IoU.
The target image is taken both ways: the copy turned as the robot sees the target (the task's) and the
copy at the target's own yaw (before). Prints the silhouette IoU of the target's views and of same-colour
look-alikes' views, and how well that one number tells them apart (ROC AUC), by the object's size.

    python baselines/target_view_match.py --scenes 60
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from mani_skill.utils.structs import Pose
from tqdm import tqdm

from mani_active_vision.boxes import roc_auc, silhouette, silhouette_iou
from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.evaluation.rollout_frames import RELATIONS, object_map, slot_relations
from mani_active_vision.evaluation.views import aimed_views

SIZE_BINS = (20, 100, 400, 1600, 10**9)
"""edges of the object's size in the wrist view, pixels"""
GREY = 128


@dataclass
class Args:
    scenes: int = 60
    """scenes (resets), seeds from `seed`"""
    seed: int = 600_000
    """first scene seed (held out)"""
    heights: tuple[float, ...] = (0.2, 0.3, 0.45, 0.65)
    object_set: str = "unseen"
    image_size: int = 128


def target_image_silhouettes(base) -> dict[str, np.ndarray]:
    """The target image's silhouette as the task takes it ("robot side") and with the copy at the target's yaw."""
    out = {}
    pose = base.target_copy.pose
    yaw = 2 * torch.atan2(base.objects[0].pose.q[:, 3], base.objects[0].pose.q[:, 0])
    for name, copy_yaw in (("robot side", None), ("own yaw", yaw)):
        if copy_yaw is not None:
            q = torch.stack([torch.cos(copy_yaw / 2), 0 * copy_yaw, 0 * copy_yaw, torch.sin(copy_yaw / 2)], -1)
            base.target_copy.set_pose(Pose.create_from_pq(pose.p, q))
        base._target_image_stale[:] = True
        image = base._render_target_image()[0].numpy()
        out[name] = silhouette((image != GREY).any(-1))
    base.target_copy.set_pose(pose)
    base._target_image_stale[:] = True
    return out


def main(args: Args):
    torch.set_num_threads(1)
    config = EnvConfig(start_pose="search", object_set=args.object_set, image_size=args.image_size)
    env = gym.make(ENV_ID, **config.task_kwargs())
    base, rows = env.unwrapped, []  # (is target, pixels, IoU robot side, IoU own yaw)
    try:
        for seed in tqdm(range(args.seed, args.seed + args.scenes), desc="scenes"):
            env.reset(seed=seed)
            references = target_image_silhouettes(base)
            relations = slot_relations(base.object_names[0], base.object_colors[0])
            slots = [0, *np.flatnonzero(relations == RELATIONS.index("same colour"))]
            for k in slots:
                for images in aimed_views(base, k, args.heights):
                    segmentation = images["segmentation"][0, ..., 0].numpy()
                    mask = object_map(base, segmentation) == k + 1
                    border = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
                    if mask.sum() < SIZE_BINS[0] or border:
                        continue
                    view = silhouette(mask)
                    rows.append(
                        (
                            k == 0,
                            mask.sum(),
                            silhouette_iou(view, references["robot side"]),
                            silhouette_iou(view, references["own yaw"]),
                        )
                    )
    finally:
        env.close()
    rows = np.array(rows, dtype=float)
    print(f"\n{len(rows)} views wholly in view ({args.object_set} objects, {args.image_size}², {args.scenes} scenes)\n")
    print("| object size (px) | target views | look-alike views | target image | IoU target | IoU look-alike | AUC |")
    print("|---|---|---|---|---|---|---|")
    for lo, hi in zip(SIZE_BINS[:-1], SIZE_BINS[1:]):
        sel = (rows[:, 1] >= lo) & (rows[:, 1] < hi)
        pos, neg = sel & (rows[:, 0] == 1), sel & (rows[:, 0] == 0)
        for column, name in ((2, "robot side"), (3, "own yaw")):
            print(
                f"| {lo}–{hi if hi < 10**9 else '…'} | {int(pos.sum())} | {int(neg.sum())} | {name} | "
                f"{rows[pos, column].mean():.2f} | {rows[neg, column].mean():.2f} | "
                f"{roc_auc(rows[pos, column], rows[neg, column]):.2f} |"
            )


if __name__ == "__main__":
    main(tyro.cli(Args))
