"""Logging functions: each logs what it is given, for env i, at the stream's current time. Entity names
live here only (the blueprint names the same ones): `world/env{i}/...` in 3D, `env{i}/...` for plots and text."""

from __future__ import annotations

import numpy as np
import rerun as rr

from mani_active_vision.directions import action_names

DEFAULT_NAMES = action_names(stay_action=True)
"""The action names where the env's set is not known: the six directions and `stay`."""

TARGET_COLOR = (230, 40, 40)
DISTRACTOR_COLORS = [
    (40, 120, 230),
    (40, 190, 90),
    (230, 170, 30),
    (170, 60, 210),
    (30, 200, 200),
    (240, 110, 180),
    (140, 140, 40),
]
ROBOT_COLOR = (150, 150, 150)
GROUND_COLOR = (0, 0, 0, 0)  # transparent: the overlay highlights objects and the robot, not the floor
MASK_COLOR = (255, 220, 0)
PATH_COLOR = (255, 160, 0)
OCCLUDER_COLOR = (158, 140, 120)


def camera(i: int) -> str:
    return f"world/env{i}/camera"


def log_episode_start(
    stream,
    i: int,
    episode: int,
    classes,
    intrinsics,
    width: int,
    height: int,
    target_image=None,
    object_positions=None,
    labels=None,
    colors=None,
):
    """The scene's segmentation classes (id, label, colour), the camera's pinhole, the target image and the
    objects' positions."""
    stream.log(f"world/env{i}", rr.AnnotationContext(classes))
    if object_positions is not None:
        stream.log(f"world/env{i}/objects", rr.Points3D(object_positions, labels=labels, colors=colors, radii=0.03))
    stream.log(
        f"{camera(i)}/image",
        rr.Pinhole(
            image_from_camera=intrinsics,
            resolution=[width, height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.15,
        ),
    )
    if target_image is not None:
        stream.log(f"env{i}/target_image", rr.Image(target_image))
    stream.log(f"env{i}/outcome", rr.TextLog(f"episode {episode} starts", level="INFO"))


def log_occluders(stream, i: int, panels: np.ndarray, size: tuple[float, float, float]):
    """The task's occluders of env i as boxes in the 3D view: panels (P, 3) = x, y, yaw; `size` =
    thickness, width, height."""
    thickness, width, height = size
    stream.log(
        f"world/env{i}/occluders",
        rr.Boxes3D(
            centers=[(x, y, height / 2) for x, y, _ in panels],
            half_sizes=[(thickness / 2, width / 2, height / 2)] * len(panels),
            rotation_axis_angles=[rr.RotationAxisAngle(axis=(0, 0, 1), radians=float(yaw)) for *_, yaw in panels],
            colors=[OCCLUDER_COLOR] * len(panels),
            labels=[f"occluder {k}" for k in range(len(panels))],
            fill_mode="solid",
        ),
    )


def log_camera_frame(
    stream,
    i: int,
    rgb: np.ndarray,
    extrinsic: np.ndarray,
    segmentation=None,
    target_box=None,
    jpeg_quality: int | None = 90,
) -> np.ndarray:
    """The camera's pose (from its OpenCV extrinsic), the wrist image (JPEG unless `jpeg_quality` is None),
    the segmentation and the ground-truth box; returns the camera's centre in the world."""
    rotation = extrinsic[:, :3].T  # world-from-camera (OpenCV axes: right, down, forward)
    centre = -rotation @ extrinsic[:, 3]
    stream.log(camera(i), rr.Transform3D(translation=centre, mat3x3=rotation))
    image = rr.Image(rgb)
    stream.log(f"{camera(i)}/image/rgb", image.compress(jpeg_quality=jpeg_quality) if jpeg_quality else image)
    height, width = rgb.shape[:2]
    if segmentation is not None:
        ids = segmentation.astype(np.uint8 if segmentation.max() < 256 else np.uint16)
        stream.log(f"{camera(i)}/image/segmentation", rr.SegmentationImage(ids, opacity=0.5))
    if target_box is not None:
        stream.log(f"{camera(i)}/image/target_box", box_2d(target_box, width, height, "ground truth", TARGET_COLOR))
    return centre


def log_mask(stream, i: int, source: str, mask: np.ndarray, box, with_context: bool = False):
    """The box state's mask (the FCN's, or the ground truth's) and the box made of it."""
    entity = f"{camera(i)}/image/{source}_mask"
    if with_context:
        classes = [(0, "background", (0, 0, 0, 0)), (1, f"{source} mask", MASK_COLOR)]
        stream.log(entity, rr.AnnotationContext(classes), static=True)
    stream.log(entity, rr.SegmentationImage(mask.astype(np.uint8), opacity=0.4))
    height, width = mask.shape
    stream.log(f"{entity}_box", box_2d(box, width, height, f"{source} box", MASK_COLOR))


def log_ee_path(stream, i: int, path: list):
    stream.log(f"world/env{i}/ee_path", rr.LineStrips3D([np.array(path)], colors=[PATH_COLOR], radii=0.004))


def log_transition(
    stream,
    i: int,
    action: np.ndarray,
    refused: bool,
    reward: float,
    success: bool,
    target_fraction: float | None,
    names: tuple[str, ...] = DEFAULT_NAMES,
):
    """What one step did: the action's name (of `names`, the env's action set), its reward, success and the
    target's fraction of the image."""
    text = action_name(action, names) + (" (refused)" if refused else "")
    stream.log(f"env{i}/action", rr.TextLog(text, level="DEBUG"))
    stream.log(f"env{i}/reward", rr.Scalars(float(reward)))
    stream.log(f"env{i}/success", rr.Scalars(float(success)))
    if target_fraction is not None:
        stream.log(f"env{i}/target_fraction", rr.Scalars(float(target_fraction)))


def log_outcome(stream, i: int, text: str, success: bool):
    stream.log(f"env{i}/outcome", rr.TextLog(text, level="INFO" if success else "WARN"))


def action_name(action: np.ndarray, names: tuple[str, ...] = DEFAULT_NAMES) -> str:
    """An action's name for an action index into `names` (the env's action set: `action_names_for`), else the
    action's numbers."""
    if action.size == 1 and np.issubdtype(action.dtype, np.integer) and 0 <= int(action[0]) < len(names):
        return names[int(action[0])]
    return np.array2string(action, precision=3)


def box_2d(box, width: int, height: int, label: str, color) -> rr.Boxes2D:
    """A normalised (x, y, w, h) box in pixels; an empty batch when nothing is seen (no box lingers)."""
    x, y, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0:
        return rr.Boxes2D(mins=np.zeros((0, 2)), sizes=np.zeros((0, 2)))
    return rr.Boxes2D(
        mins=[[x * width, y * height]],
        sizes=[[w * width, h * height]],
        labels=[label],
        colors=[color],
        show_labels=False,
    )
