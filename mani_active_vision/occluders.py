"""Occluders: upright panels that hide an object from the search height (the task's `occluders` option).

Panel k stands between the robot's base and object k (object 0 is the target), facing the base, at a
random sideways offset. Its distance in front of the object is chosen so that the line of sight from the
search pose's camera to the object's farthest, highest point passes `HIDE_MARGIN` below its top: straight
in front, it hides the whole object from the search height; offset, part of it, or none. From closer and
higher viewpoints (over the panel, or past it) the object is in view again. docs/task.md#occluders gives
how often the target is hidden and the success ceiling.

Panels are visual only and kinematic, like the objects. The controller refuses a step that would put the
camera end of the arm (joint 6 to the camera) inside one (`points_inside`); the rest of the arm is not
checked and can pass through a panel's top when the camera looks down behind it (docs/task.md#occluders).
"""

from __future__ import annotations

import math

import numpy as np
import sapien
import torch

from mani_active_vision.objects import OBJECT_SIZE

PANEL_SIZE = (0.02, 0.20, 0.50)
"""thickness (radial), width and height of a panel (m)"""
PANEL_COLOR = (0.62, 0.55, 0.47)
"""a greyish brown, unlike every colour of the objects' palette and the floor"""
HIDE_MARGIN = 0.02
"""the search camera's line of sight to an object's far top passes this far below the panel's top (m)"""
MAX_OFFSET = 0.16
"""largest sideways offset of a panel's centre from the line base -> object (m)"""
CLEARANCE = 0.02
"""least gap between a panel and any object or other panel (m)"""
MIN_VISIBLE_FRACTION = 0.98
"""success needs at least this share of the target's pixels in view not hidden by a panel (a pixel or two
where a panel's edge meets the target's silhouette does not hide its extent)"""
ARM_MARGIN = 0.04
"""the arm's camera end (radius ~4 cm) keeps this far from a panel (m)"""


def panel_distance(object_radius: float, camera_rz: tuple[float, float]) -> float:
    """How far in front of an object (toward the base, m) a panel stands so that the line of sight from a
    camera at (radius, height) `camera_rz` to the object's farthest, highest point (largest object size
    assumed) passes `HIDE_MARGIN` below the panel's top."""
    cam_r, cam_z = camera_rz
    half, top = OBJECT_SIZE[1] / 2, OBJECT_SIZE[1]
    far_r = object_radius + half
    height_needed = PANEL_SIZE[2] - HIDE_MARGIN - top  # above the object's top, at the panel
    return height_needed * (far_r - cam_r) / (cam_z - top) - half


def panel_corners(x: float, y: float, yaw: float) -> np.ndarray:
    """The four floor corners (4, 2) of a panel centred at (x, y) with its thickness along `yaw`."""
    half_t, half_w = PANEL_SIZE[0] / 2, PANEL_SIZE[1] / 2
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[half_t, half_w], [half_t, -half_w], [-half_t, -half_w], [-half_t, half_w]])
    return np.array([x, y]) + local @ np.array([[c, s], [-s, c]])


def _distance_to_panel(points: np.ndarray, panel: np.ndarray) -> np.ndarray:
    """Floor distance (M,) from points (M, 2) to a panel (x, y, yaw) footprint (0 inside)."""
    x, y, yaw = panel
    c, s = math.cos(yaw), math.sin(yaw)
    d = points - [x, y]
    local = np.stack([d @ [c, s], d @ [-s, c]], -1)
    excess = np.abs(local) - [PANEL_SIZE[0] / 2, PANEL_SIZE[1] / 2]
    return np.linalg.norm(np.maximum(excess, 0), axis=-1)


def place_panels(rng: np.random.RandomState, objects_xy: np.ndarray, count: int, camera_rz) -> np.ndarray | None:
    """Panels (count, 3) = x, y, yaw in front of objects 0..count-1 of `objects_xy` (K, 2), each at a random
    sideways offset, none within `CLEARANCE` of an object or another panel. None when some panel finds no
    free spot in 100 draws (the caller draws a new layout)."""
    object_radius = OBJECT_SIZE[1] / 2
    panels = []
    for k in range(count):
        r = float(np.linalg.norm(objects_xy[k]))
        azimuth = math.atan2(objects_xy[k, 1], objects_xy[k, 0])
        centre_r = r - panel_distance(r, camera_rz)
        for _ in range(100):
            offset = rng.uniform(-MAX_OFFSET, MAX_OFFSET)
            sideways = np.array([-math.sin(azimuth), math.cos(azimuth)])
            xy = centre_r * np.array([math.cos(azimuth), math.sin(azimuth)]) + offset * sideways
            panel = np.array([*xy, azimuth])
            corners = panel_corners(*panel)
            clear_of_objects = _distance_to_panel(objects_xy, panel).min() >= object_radius + CLEARANCE
            clear_of_panels = all(_distance_to_panel(corners, other).min() >= CLEARANCE for other in panels)
            if clear_of_objects and clear_of_panels:
                panels.append(panel)
                break
        else:
            return None
    return np.stack(panels) if panels else np.zeros((0, 3))


def points_inside(points: torch.Tensor, panels: torch.Tensor, margin: float = ARM_MARGIN) -> torch.Tensor:
    """Which of the points (N, P, 3) lie within `margin` of a panel of their env (N, K, 3) = x, y, yaw
    (panels stand on the floor): (N, P) bool."""
    if panels.shape[1] == 0:
        return torch.zeros(points.shape[:2], dtype=torch.bool, device=points.device)
    d = points[:, :, None, :2] - panels[:, None, :, :2]  # (N, P, K, 2)
    c, s = torch.cos(panels[..., 2])[:, None], torch.sin(panels[..., 2])[:, None]
    along, across = d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c
    thickness, width, height = PANEL_SIZE
    inside = (along.abs() <= thickness / 2 + margin) & (across.abs() <= width / 2 + margin)
    inside &= points[:, :, None, 2] <= height + margin
    return inside.any(-1)


def build_panel(scene, name: str, scene_idxs=None):
    """A kinematic, visual-only panel actor; its origin at the centre of its footprint, on the floor."""
    thickness, width, height = PANEL_SIZE
    builder = scene.create_actor_builder()
    material = sapien.render.RenderMaterial(base_color=[*PANEL_COLOR, 1.0], roughness=0.8)
    half_size = [thickness / 2, width / 2, height / 2]
    builder.add_box_visual(pose=sapien.Pose(p=[0, 0, height / 2]), half_size=half_size, material=material)
    if scene_idxs is not None:
        builder.set_scene_idxs(scene_idxs)
    builder.initial_pose = sapien.Pose(p=[0, 0, -20.0 - 10 * len(scene.actors)])
    return builder.build_kinematic(name=name)
