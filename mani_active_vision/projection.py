"""Render-free target masks: the target's convex hull projected into the wrist camera (the task's `render_free`).

A rendered step spends most of its time waiting for the frame (docs/speed.md). For state-based training the
target's mask can instead be drawn from geometry: the hull points of the target's mesh are moved by its pose,
projected with the camera's pinhole (the camera's pose from link 7's, so nothing is rendered), and the pixels
whose centres fall inside their convex hull make the mask. It is an approximation, and it is only used when
asked for: a concave object covers less than its hull, and nothing hides the target (no other object, no
occluder). `baselines/projection_error.py` measures the difference to the rendered segmentation.
"""

from __future__ import annotations

import numpy as np
import scipy.spatial
import torch

CV_FROM_SAPIEN = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
"""SAPIEN's camera axes (x forward, y left, z up) to OpenCV's (x right, y down, z forward)"""


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4) = w, x, y, z (SAPIEN's order)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def extrinsic_cv(mount_pose: np.ndarray, local_pose: np.ndarray) -> np.ndarray:
    """World -> camera (N, 3, 4) in OpenCV axes, for a camera at `local_pose` (7,) = p, q in the frame of a
    link at `mount_pose` (N, 7) = p, q (ManiSkill's raw poses)."""
    link = rotation_matrix(mount_pose[:, 3:])
    rotation = link @ rotation_matrix(local_pose[None, 3:])  # world <- camera (SAPIEN axes)
    position = mount_pose[:, :3] + link @ local_pose[:3]
    to_camera = rotation.transpose(0, 2, 1)
    return CV_FROM_SAPIEN @ np.concatenate([to_camera, -to_camera @ position[:, :, None]], -1)


def hull_mask(points: np.ndarray, extrinsic: np.ndarray, intrinsic: np.ndarray, size: int, near: float = 0.01):
    """(N, size, size) bool tensor: the pixels whose centres lie in the convex hull of the points (N, V, 3,
    world) projected by the camera (extrinsic (N, 3, 4), intrinsic (N, 3, 3)); points behind the near plane
    are left out."""
    camera = points @ extrinsic[:, :, :3].transpose(0, 2, 1) + extrinsic[:, None, :, 3]  # (N, V, 3)
    masks = np.zeros((len(points), size, size), dtype=bool)
    for i in range(len(points)):
        front = camera[i, camera[i, :, 2] > near]
        if len(front) < 3:
            continue
        pixels = (front @ intrinsic[i].T)[:, :2] / front[:, 2:]
        # only the pixels of the hull's bounding box are tested
        (u0, v0), (u1, v1) = np.clip(np.floor(pixels.min(0)), 0, size), np.clip(np.ceil(pixels.max(0)), 0, size)
        if u0 >= u1 or v0 >= v1:
            continue  # wholly outside the image
        try:
            hull = scipy.spatial.ConvexHull(pixels)
        except scipy.spatial.QhullError:  # degenerate (seen edge-on): no area
            continue
        u, v = np.meshgrid(np.arange(u0, u1) + 0.5, np.arange(v0, v1) + 0.5)
        a, b, c = hull.equations.T
        inside = (u[..., None] * a + v[..., None] * b + c <= 0).all(-1)
        masks[i, int(v0) : int(v1), int(u0) : int(u1)] = inside
    return torch.from_numpy(masks)
