"""Privileged view planning: the camera is put straight at lattice poses near the target (joint positions
set, no stepping) and each wrist view is judged against the success criterion. Behind the ceilings of
what any policy can do: reaching success (`baselines/success_reachability.py`) and holding it
(`baselines/hold_ceiling.py`). Reads the target's position: for measurements only, never for a policy."""

from __future__ import annotations

import math

import numpy as np
import torch

from mani_active_vision.boxes import target_stats
from mani_active_vision.directions import DIRECTIONS, direction_deltas
from mani_active_vision.occluders import MIN_VISIBLE_FRACTION
from mani_active_vision.robots.iiwa import CAMERA_PITCH, SEARCH_POS
from mani_active_vision.robots.orbit_controller import OrbitEEPosControllerConfig, solve_ik, step_allowed

REVERSE = {"left": "right", "right": "left", "forward": "backward", "backward": "forward", "up": "down", "down": "up"}
"""The direction that undoes each direction exactly (docs/design.md §3: the lattice is exact)."""


def candidate_positions(target_xy: np.ndarray, step: float, pitch: float, min_height: float) -> np.ndarray:
    """Lattice points (M, 3) near the target that forward/backward and up/down steps reach from the search
    pose (a radius/height lattice), at azimuths in 2° steps within ±12° of the target's (orbiting at
    different radii reaches nearly any azimuth)."""
    r_t = float(np.linalg.norm(target_xy))
    az_t = math.atan2(target_xy[1], target_xy[0])
    forward_r, forward_z = step * math.cos(pitch), -step * math.sin(pitch)
    points = []
    for a in range(-10, 40):
        for b in range(-20, 20):
            r = SEARCH_POS[0] + a * forward_r
            z = SEARCH_POS[2] + a * forward_z + b * step
            if r_t - 0.45 <= r <= r_t - 0.02 and min_height <= z <= 0.6:
                for d_az in np.radians(np.arange(-12, 12.1, 2.0)):
                    points.append((r * math.cos(az_t + d_az), r * math.sin(az_t + d_az), z))
    return np.array(points)


def view_stats(base, qpos: torch.Tensor) -> dict[str, np.ndarray]:
    """The target's statistics (`boxes.target_stats`, as numpy arrays of M) in the wrist views of the arm
    set to each of the joint positions `qpos` (M, 7) of env 0. Leaves the arm at the last one."""
    rows = []
    for q in qpos:
        base.agent.robot.set_qpos(q[None])
        base.forget_view()
        seg = base._hand_camera_images()["segmentation"][..., 0]
        target = seg == base.target_seg_id[:, None, None]
        rows.append({**target_stats(target), "target_visible_fraction": base._visible_fraction(seg, target)})
    keys = ("target_fraction", "target_visible", "target_visible_fraction", "touches_border", "center_offset")
    return {k: np.array([float(r[k][0]) for r in rows]) for k in keys}


def meets(stats: dict, fraction, tolerance) -> np.ndarray:
    """Which views meet the success criterion (fully in view and not hidden by an occluder, share >=
    `fraction`, centroid within `tolerance` of the width from the centre); `fraction` and `tolerance` may
    be broadcast arrays."""
    inside = (stats["target_visible"] > 0) & (stats["touches_border"] == 0)
    inside &= stats["target_visible_fraction"] >= MIN_VISIBLE_FRACTION
    return inside & (stats["target_fraction"] >= fraction) & (stats["center_offset"] <= tolerance)


def neighbours(positions: torch.Tensor, qpos: torch.Tensor, step: float, config, names=DIRECTIONS):
    """The poses one action away from each pose: positions (M, K, 3), joint positions (M, K, 7) and whether
    the controller accepts each step (M, K) (`step_allowed`; a refused step leaves the arm where it is)."""
    next_pos = positions[:, None, :] + direction_deltas(positions, step, config.pitch, names)
    flat_q, allowed = step_allowed(next_pos.reshape(-1, 3), qpos.repeat_interleave(len(names), 0), config)
    return next_pos, flat_q.reshape(len(positions), len(names), 7), allowed.reshape(len(positions), len(names))


def aimed_qpos(xy: np.ndarray, height: float) -> torch.Tensor | None:
    """Joint positions that aim the camera's optical axis at floor point `xy` from `height`, or None."""
    bounds = OrbitEEPosControllerConfig
    radius = float(np.linalg.norm(xy)) - height / math.tan(CAMERA_PITCH)
    azimuth = math.atan2(xy[1], xy[0])
    pos = torch.tensor([[radius * math.cos(azimuth), radius * math.sin(azimuth), height]], dtype=torch.float32)
    qpos, ok = solve_ik(pos, CAMERA_PITCH)
    if not ok[0] or not bounds.min_radius <= radius <= bounds.max_radius or float(qpos[0, 3]) > bounds.max_elbow:
        return None
    return qpos


def aimed_views(base, slot: int, heights):
    """Yields the wrist camera's images (`_hand_camera_images` of env 0) aimed at object `slot` of a reset task
    from each of `heights` (m) the camera can reach there (`aimed_qpos`); the arm is set straight to each pose,
    one view at a time."""
    for height in heights:
        qpos = aimed_qpos(base.objects[slot].pose.p[0, :2].numpy(), height)
        if qpos is not None:
            base.agent.robot.set_qpos(qpos)
            base.forget_view()
            yield base._hand_camera_images()
