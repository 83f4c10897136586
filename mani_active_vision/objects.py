"""Object sets and their builders: procedural meshes and named models from `pybullet_data`, and primitives.

Split once, by a fixed rule (docs/design.md §7): `train` = random_urdfs 000-799; `unseen` = random_urdfs 800-999
plus the named models (duck, teddy, mug, lego), never used to train the FCN or an agent; `primitives` =
boxes, cylinders and spheres in a small palette. Every object is scaled to a largest extent of 7-10 cm.
"""

from __future__ import annotations

import itertools
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache

import numpy as np
import pybullet_data
import sapien
import scipy.spatial
import trimesh

OBJECT_SETS = ("train", "unseen", "primitives")
OBJECT_SIZE = (0.07, 0.10)
"""Range of an object's largest extent (m)."""
PALETTE = (
    (0.85, 0.15, 0.15),
    (0.15, 0.65, 0.20),
    (0.15, 0.30, 0.85),
    (0.90, 0.80, 0.15),
    (0.85, 0.45, 0.10),
    (0.60, 0.20, 0.75),
    (0.10, 0.70, 0.75),
    (0.95, 0.95, 0.95),
)
PRIMITIVE_SHAPES = ("box", "cylinder", "sphere")
NAMED_MODELS = ("duck_vhacd.urdf", "teddy_vhacd.urdf", "objects/mug.urdf", "lego/lego.urdf")


@dataclass(frozen=True)
class ObjectModel:
    """One object: a mesh (with its URDF scale and colour) or a primitive shape."""

    name: str
    shape: str  # "mesh" or one of PRIMITIVE_SHAPES
    color: tuple
    mesh_path: str | None = None
    mesh_scale: float = 1.0


def _model_from_urdf(urdf_path: str) -> ObjectModel:
    visual = ET.parse(urdf_path).getroot().find(".//visual")
    mesh = visual.find("./geometry/mesh")
    color = visual.find("./material/color")
    rgba = [float(v) for v in color.get("rgba").split()] if color is not None else [0.7, 0.7, 0.7, 1]
    scale = float(mesh.get("scale", "1 1 1").split()[0])
    name = os.path.splitext(os.path.basename(urdf_path))[0].replace("_vhacd", "")
    path = os.path.join(os.path.dirname(urdf_path), mesh.get("filename"))
    return ObjectModel(name=name, shape="mesh", color=tuple(rgba[:3]), mesh_path=path, mesh_scale=scale)


@cache
def object_set(name: str) -> tuple[ObjectModel, ...]:
    """The models of object set `name` (one of OBJECT_SETS), in a fixed order."""
    if name not in OBJECT_SETS:
        raise ValueError(f"object_set={name!r} is not one of: {', '.join(OBJECT_SETS)}")
    root = pybullet_data.getDataPath()
    if name == "primitives":
        return tuple(
            ObjectModel(name=f"{shape}_{i}", shape=shape, color=color)
            for shape in PRIMITIVE_SHAPES
            for i, color in enumerate(PALETTE)
        )
    ids = range(0, 800) if name == "train" else range(800, 1000)
    models = [_model_from_urdf(os.path.join(root, "random_urdfs", f"{i:03d}", f"{i:03d}.urdf")) for i in ids]
    if name == "unseen":
        models += [_model_from_urdf(os.path.join(root, path)) for path in NAMED_MODELS]
    return tuple(models)


@cache
def _mesh_bounds(path: str) -> np.ndarray:
    mesh = trimesh.load(path, force="mesh", process=False)
    return np.asarray(mesh.bounds, dtype=np.float64)


def unit_bounds(model: ObjectModel) -> np.ndarray:
    """Axis-aligned bounds (2, 3) of the model at scale 1 (primitives: a unit-size shape)."""
    if model.shape == "mesh":
        return _mesh_bounds(model.mesh_path) * model.mesh_scale
    return np.array([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])


@cache
def _unit_hull(path: str) -> np.ndarray:
    mesh = trimesh.load(path, force="mesh", process=False)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    vertices = vertices[np.isfinite(vertices).all(1)]
    if len(vertices) < 4:  # random_urdfs/168 reads as NaN vertices only (its bounds are NaN too)
        return np.array(list(itertools.product((-0.5, 0.5), repeat=3)))
    return vertices[scipy.spatial.ConvexHull(vertices).vertices]


def hull_points(model: ObjectModel, size: float) -> np.ndarray:
    """Points (V, 3) in the actor's frame whose convex hull is that of the object `build_object` makes (for
    render-free masks: `mani_active_vision.projection`)."""
    bounds = unit_bounds(model)
    scale = size / float((bounds[1] - bounds[0]).max())
    half = size / 2
    if model.shape == "mesh":
        return _unit_hull(model.mesh_path) * model.mesh_scale * scale
    if model.shape == "box":
        return np.array(list(itertools.product(*[(-h, h) for h in (half, half * 0.8, half * 0.7)])))
    if model.shape == "sphere":  # a Fibonacci lattice of 64 points on the sphere
        k = np.arange(64) + 0.5
        polar, azimuth = np.arccos(1 - 2 * k / 64), np.pi * (1 + 5**0.5) * k
        return half * np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], -1)
    angle = np.linspace(0, 2 * np.pi, 32, endpoint=False)  # cylinder, upright
    ring = np.stack([half * 0.6 * np.cos(angle), half * 0.6 * np.sin(angle)], -1)
    return np.concatenate([np.c_[ring, np.full(32, -half)], np.c_[ring, np.full(32, half)]])


def build_object(scene, model: ObjectModel, size: float, color, name: str, scene_idxs=None, collision=False):
    """A kinematic actor (objects never roll or tumble) of `model` scaled to largest extent `size`.

    Without `collision` (the default) the object is visual only: nothing in the task touches objects
    (the camera has no collision body and the workspace keeps link 7 at least 10 cm above the floor),
    and skipping convex hulls halves the time to load a new scene.

    Returns (actor, bottom): `bottom` is the height of the object's lowest point above its origin's
    height, negated: place the origin at z = bottom to rest it on the floor.
    """
    bounds = unit_bounds(model)
    scale = size / float((bounds[1] - bounds[0]).max())
    material = sapien.render.RenderMaterial(base_color=[*color, 1.0], roughness=0.6)
    builder = scene.create_actor_builder()
    half = size / 2
    if model.shape == "mesh":
        s = [model.mesh_scale * scale] * 3
        builder.add_visual_from_file(model.mesh_path, scale=s, material=material)
        if collision:
            builder.add_convex_collision_from_file(model.mesh_path, scale=s)
        bottom = -bounds[0, 2] * scale
    elif model.shape == "box":
        builder.add_box_visual(half_size=[half, half * 0.8, half * 0.7], material=material)
        if collision:
            builder.add_box_collision(half_size=[half, half * 0.8, half * 0.7])
        bottom = half * 0.7
    elif model.shape == "sphere":
        builder.add_sphere_visual(radius=half, material=material)
        if collision:
            builder.add_sphere_collision(radius=half)
        bottom = half
    else:  # cylinder, upright (SAPIEN's cylinders lie along x)
        upright = sapien.Pose(q=[math.sqrt(0.5), 0, math.sqrt(0.5), 0])
        builder.add_cylinder_visual(pose=upright, radius=half * 0.6, half_length=half, material=material)
        if collision:
            builder.add_cylinder_collision(pose=upright, radius=half * 0.6, half_length=half)
        bottom = half
    if scene_idxs is not None:
        builder.set_scene_idxs(scene_idxs)
    builder.initial_pose = sapien.Pose(p=[0, 0, -10.0 - 10 * len(scene.actors)])
    return builder.build_kinematic(name=name), bottom
