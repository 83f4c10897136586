"""How far the render-free mask (the target's hull projected: `box_source="projection"`) is from the rendered one.

The scripted servo acts on the rendered ground-truth box; on every step the task's projected mask of the
same view is compared with the rendered segmentation's: mask IoU (steps where either has the target), box
error (mean |Δ| of the normalised x, y, w, h), the target's share of the image (projected / rendered), and
whether the two agree on "in view" and on success. Episode seeds from 1,000,000 (held out).

    .venv/bin/python baselines/projection_error.py --episodes 20 --env.object-set unseen
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
import tyro
from tqdm import tqdm

from mani_active_vision.agents.policies import make_policy
from mani_active_vision.boxes import mask_to_box, target_stats
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.protocol import EVAL_SEED, eval_seeds
from mani_active_vision.evaluation.rollout import run_episode


@dataclass
class Args:
    env: EnvConfig = field(default_factory=lambda: EnvConfig(object_set="unseen"))
    """the rendered env the servo runs in (its box source is the ground truth)"""
    episodes: int = 20
    seed: int = EVAL_SEED


def compare(base, rendered: torch.Tensor) -> dict:
    """The projected and the rendered target mask (1, H, W) of the current view, compared."""
    projected = base.projected_target_mask()
    union = int((projected | rendered).sum())
    p, r = target_stats(projected), target_stats(rendered)

    def success(s):
        return bool(
            s["target_visible"][0]
            and not s["touches_border"][0]
            and s["center_offset"][0] <= base.success_center_tol
            and s["target_fraction"][0] >= base.success_fraction
        )

    return dict(
        iou=int((projected & rendered).sum()) / union if union else None,
        box_error=float((mask_to_box(projected) - mask_to_box(rendered)).abs().mean()) if union else None,
        share_ratio=float(p["target_fraction"][0] / r["target_fraction"][0]) if r["target_visible"][0] else None,
        agree_in_view=bool(p["target_visible"][0]) == bool(r["target_visible"][0]),
        agree_success=success(p) == success(r),
        success=success(r),
    )


def main(args: Args):
    torch.set_num_threads(1)
    env = make_env(args.env.replace(box_source="ground_truth"))
    base = env.unwrapped
    policy = make_policy("servo", env)
    rows = []

    def on_step(obs, info):
        base.forget_view()  # then project this view (the rendered env does not)
        rows.append(compare(base, env.last_mask.cpu()))

    for seed in tqdm(eval_seeds(args.episodes, args.seed), desc="episodes"):
        run_episode(env, policy, seed, on_step=on_step)
    env.close()

    def mean(key, where=lambda r: True):
        values = [r[key] for r in rows if r[key] is not None and where(r)]
        return (float(np.mean(values)), len(values)) if values else (float("nan"), 0)

    print(
        f"\nProjected against rendered target masks: {len(rows)} views of the servo's {args.episodes} episodes "
        f"({args.env.object_set} objects, {args.env.image_size}²)\n"
    )
    print("| measure | value | views |")
    print("|---|---|---|")
    for label, (value, n) in (
        ("mask IoU (either has the target)", mean("iou")),
        ("box error, mean abs of x, y, w, h", mean("box_error")),
        ("target share, projected / rendered", mean("share_ratio")),
        ("agree on in view", mean("agree_in_view")),
        ("agree on success", mean("agree_success")),
        ("agree on success, where rendered success", mean("agree_success", lambda r: r["success"])),
    ):
        print(f"| {label} | {value:.3f} | {n} |")


if __name__ == "__main__":
    main(tyro.cli(Args))
