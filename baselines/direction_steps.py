"""How far, and how straight, each of the six directions moves the camera: mean ± std over many steps.

From the search pose of several seeds, takes `steps` steps of each direction (refused steps are counted,
not measured) and prints the displacement of link 7 (the camera) per step, its error against the intended
direction, and the camera's tilt against the orientation rule.

    .venv/bin/python baselines/direction_steps.py
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import tyro

import mani_active_vision as mav
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.robots.orbit_controller import camera_forward


@dataclass
class Args:
    seeds: int = 5
    """episodes (seeds 0..seeds-1) per direction"""
    steps: int = 4
    """steps of one direction per episode"""


def intended(name: str, pos: torch.Tensor, pitch: float) -> torch.Tensor:
    """Unit vector a step of `name` should move along, at camera position `pos`."""
    azimuth = torch.atan2(pos[1], pos[0])
    tangent = torch.stack([-torch.sin(azimuth), torch.cos(azimuth), torch.zeros(())])  # left = counter-clockwise
    forward = camera_forward(azimuth[None], pitch)[0].to(pos.dtype)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=pos.dtype)
    return {"left": tangent, "right": -tangent, "forward": forward, "backward": -forward, "up": up, "down": -up}[name]


def main(args: Args):
    torch.set_num_threads(1)
    env = make_env(EnvConfig(start_pose="search", box_source="none"))
    base = env.unwrapped
    pitch = base.agent.controller.config.pitch
    print(f"step_size {base.step_size} m; {args.seeds} seeds x {args.steps} steps per direction\n")
    print("| direction | displacement mm (mean ± std) | off-axis mm (max) | tilt deg (max) | refused |")
    print("|---|---|---|---|---|")
    for index, name in enumerate(mav.DIRECTIONS):
        lengths, off_axis, tilts, refused = [], [], [], 0
        for seed in range(args.seeds):
            env.reset(seed=seed)
            for _ in range(args.steps):
                before = base.agent.ee_pose.p[0].double()
                _, _, _, _, info = env.step(index)
                if bool(info["refused"][0]):
                    refused += 1
                    continue
                moved = base.agent.ee_pose.p[0].double() - before
                # left/right follow an arc: compare against the chord's direction at the arc's midpoint
                mid = before + moved / 2
                unit = intended(name, mid, pitch)
                lengths.append(float(torch.linalg.norm(moved)))
                off_axis.append(float(torch.linalg.norm(moved - (moved @ unit) * unit)))
                rot = base.agent.ee_pose.to_transformation_matrix()[0, :3, :3].double()
                az = torch.atan2(base.agent.ee_pose.p[0, 1], base.agent.ee_pose.p[0, 0])
                view = camera_forward(az[None], pitch)[0].double()
                tilts.append(
                    max(
                        math.degrees(math.acos(float(torch.clamp(rot[:, 2] @ view, -1, 1)))),
                        math.degrees(math.asin(abs(float(rot[2, 1])))),
                    )
                )
        lengths = 1000 * np.array(lengths)
        print(
            f"| {name} | {lengths.mean():.2f} ± {lengths.std():.2f} | {1000 * max(off_axis):.2f} | {max(tilts):.3f} | {refused} |"
        )
    env.close()


if __name__ == "__main__":
    main(tyro.cli(Args))
