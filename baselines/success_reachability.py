"""How often can the success criterion be met? Measures it for candidate thresholds, privileged.

For each random placement (seed), the camera is put (joint positions set directly, no stepping) at every
point of the lattice that the six directions reach near the target (radius/height lattice of forward and
up/down steps from the start pose; azimuth in fine steps around the target's, since orbiting at different
radii reaches nearly any azimuth) and the wrist view is rendered. A placement counts as reachable for a
(fraction, tolerance) pair when any candidate view meets it. The default success criterion of
ActiveVisionFind-v0 is chosen from this table.

    .venv/bin/python baselines/success_reachability.py --placements 40
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from tqdm import tqdm

import mani_active_vision  # noqa: F401
from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.evaluation.views import candidate_positions, meets, view_stats
from mani_active_vision.json_io import save_json
from mani_active_vision.occluders import points_inside
from mani_active_vision.robots.orbit_controller import arm_points, camera_end, solve_ik


@dataclass
class Args:
    placements: int = 40
    """number of random placements (seeds seed..seed+placements-1)"""
    seed: int = 0
    """first placement's seed (1_000_000: the held-out evaluation episodes of `baselines/evaluate.py`)"""
    resolution: int = 128
    """wrist camera width = height"""
    object_set: str = "train"
    placement: str = "random"
    """"random", or "fixed" (the paper's fixed scene: then one placement is enough)"""
    fractions: tuple[float, ...] = (0.05, 0.10, 0.15, 0.20)
    tolerances: tuple[float, ...] = (0.10, 0.15, 0.20)
    occluders: int = 0
    """panels per scene (the task's `occluders`): views with the camera end of the arm in a panel are left out"""
    json: str = ""
    """also write, per placement (seed), how many candidate views meet the task's criterion (to split an
    evaluation's episodes by it)"""
    whole_arm: bool = False
    """also leave out views where any part of the arm (radius ~6 cm) passes through a panel (the controller
    checks only the camera end)"""


def main(args: Args):
    torch.set_num_threads(1)
    config = EnvConfig(
        start_pose="search",
        object_set=args.object_set,
        placement=args.placement,
        image_size=args.resolution,
        occluders=args.occluders,
    )
    env = gym.make(ENV_ID, **config.task_kwargs())
    base = env.unwrapped
    controller = base.agent.controller
    reachable = np.zeros((len(args.fractions), len(args.tolerances)))
    task_views = {}  # seed: how many candidate views meet the task's own criterion
    for seed in tqdm(range(args.seed, args.seed + args.placements), desc="placements"):
        env.reset(seed=seed)
        target_xy = base.target.pose.p[0, :2].numpy()
        points = torch.as_tensor(
            candidate_positions(target_xy, base.step_size, controller.config.pitch, controller.config.min_height),
            dtype=torch.float32,
        )
        qpos, ok = solve_ik(points, controller.config.pitch)
        ok &= qpos[:, 3] <= controller.config.max_elbow
        panels = base.panel_layout().expand(len(points), -1, -1)
        ok &= ~points_inside(camera_end(points, controller.config.pitch), panels).any(-1)
        if args.whole_arm:
            ok &= ~points_inside(arm_points(qpos), panels, margin=0.06).any(-1)
        stats = {k: v[:, None, None] for k, v in view_stats(base, qpos[ok]).items()}  # (views, 1, 1)
        fractions, tolerances = np.array(args.fractions)[:, None], np.array(args.tolerances)[None, :]
        reachable += meets(stats, fractions, tolerances).any(0)
        task_views[seed] = int(meets(stats, config.success_fraction, config.success_center_tol).sum())
    env.close()
    share = reachable / args.placements
    print(
        f"\nShare of {args.placements} {args.placement} placements ({args.object_set} objects, {args.resolution}², "
        f"{args.occluders} occluders) where some view"
    )
    print("is fully in view with target share >= fraction and centroid within tolerance·W of the centre:\n")
    print("| fraction \\ tolerance | " + " | ".join(f"{t:.2f}" for t in args.tolerances) + " |")
    print("|---|" + "---|" * len(args.tolerances))
    for i, f in enumerate(args.fractions):
        print(f"| {f:.2f} | " + " | ".join(f"{share[i, j]:.2f}" for j in range(len(args.tolerances))) + " |")
    counts = np.array(list(task_views.values()))
    print(
        f"\nViews meeting the task's criterion ({config.success_fraction} / {config.success_center_tol}) per placement: "
        f"median {np.median(counts):.0f}; none {int((counts == 0).sum())}, 1-2 "
        f"{int(((counts >= 1) & (counts <= 2)).sum())}, 3 or more {int((counts >= 3).sum())} placements"
    )
    print(f"without any: seeds {[seed for seed, n in task_views.items() if n == 0]}")
    print(f"with 1-2 (a policy must hit them exactly): seeds {[seed for seed, n in task_views.items() if 1 <= n <= 2]}")
    if args.json:
        save_json({"args": dataclasses.asdict(args), "views_in_success": task_views}, args.json)
        print(f"views per placement written to {args.json}")


if __name__ == "__main__":
    main(tyro.cli(Args))
