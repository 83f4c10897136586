"""Render a segmentation data set for the one-shot FCN from ActiveVisionFind-v0 (shards + manifest.json).

The default command set used for the shipped weights (`scripts/make_fcn.sh` runs them all):
  python baselines/collect_segmentation_data.py --out-dir data/seg64/train --object-set train --num-scenes 1500 --seed 0 --workers 2
  ... val (train objects, seed 100000), test_train (seed 200000), test_unseen (unseen objects, seed 300000)
  python baselines/collect_segmentation_data.py --out-dir data/seg64_occ2/test_unseen --object-set unseen --num-scenes 50 --seed 320000 --occluders 2
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.segmentation_data import SegmentationDataConfig, collect_segmentation_data


@dataclass
class Args:
    out_dir: str = "data/seg64/train"
    """folder for the shards and manifest.json"""
    object_set: str = "train"
    """train | unseen | primitives (the unseen set is never used for training)"""
    num_scenes: int = 1500
    """scenes (resets with new objects); samples = num_scenes * views_per_scene"""
    views_per_scene: int = 20
    """camera poses rendered per scene"""
    image_size: int = 64
    """wrist view side in pixels"""
    seed: int = 0
    """scene k is reset with seed + k: keep splits' seed ranges apart"""
    scenes_per_shard: int = 50
    """scenes per .npz shard"""
    workers: int = 1
    """rendering processes (shards are spread over them; the data do not depend on it)"""
    view_mode_probs: tuple[float, ...] = SegmentationDataConfig.view_mode_probs
    """probabilities of the view modes (segmentation_data.VIEW_MODES: target, distractor, anywhere, lookalike)"""
    occluders: int = 0
    """the task's panels per scene: targets partly hidden, panels in view (docs/task.md#occluders)"""


def main(args: Args):
    torch.set_num_threads(1)
    config = SegmentationDataConfig(
        object_set=args.object_set,
        num_scenes=args.num_scenes,
        views_per_scene=args.views_per_scene,
        image_size=args.image_size,
        seed=args.seed,
        view_mode_probs=args.view_mode_probs,
        occluders=args.occluders,
    )
    manifest = collect_segmentation_data(
        args.out_dir, config, scenes_per_shard=args.scenes_per_shard, workers=args.workers
    )
    summary = {k: manifest[k] for k in ("num_samples", "share_with_target", "target_pixel_share", "seconds")}
    print(f"{args.out_dir}: {json.dumps(summary)}")


if __name__ == "__main__":
    main(tyro.cli(Args))
