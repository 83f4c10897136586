"""Render a test set of frames from rollouts of the project's policies (servo, exploration -> servo, random
from both start poses; ground-truth box; unseen objects; held-out seeds; 128²), with each pixel's object
and each object's relation to the target, for `baselines/eval_fcn.py` (which then attributes false
positives).

    python baselines/collect_rollout_frames.py --out-dir data/rollout128/test_unseen
    python baselines/eval_fcn.py --largest-component --data-dirs data/rollout128/test_unseen
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import tyro

from mani_active_vision.evaluation.rollout_frames import RolloutFramesConfig, collect_rollout_frames


@dataclass
class Args:
    out_dir: str = "data/rollout128/test_unseen"
    """folder for the shards and manifest.json"""
    config: RolloutFramesConfig = field(default_factory=RolloutFramesConfig)


def main(args: Args):
    torch.set_num_threads(1)
    manifest = collect_rollout_frames(args.out_dir, args.config)
    print(
        f"{args.out_dir}: {manifest['num_samples']} frames, {manifest['share_with_target']:.2f} with the target, "
        f"{manifest['seconds']:.0f} s"
    )


if __name__ == "__main__":
    main(tyro.cli(Args))
