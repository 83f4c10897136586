"""The floor: ManiSkill's checkered ground (1 m squares, its grid texture, 100 m wide), drawn in nine pieces.

ManiSkill's `build_ground` is one mesh of 20,000 triangles, which the software renderer transforms and
clips for every frame of the wrist camera, although that camera sees the floor only within a few metres
of the robot (it looks 60° down from at most ~1.3 m up: the floor it sees is within ~4 m of the base).
Here the same squares, with the same vertices, texture coordinates and triangles, are cut into the centre
(|x|, |y| <= 5 m: 200 triangles) and eight pieces around it, each its own render body, so that culling
(`mani_active_vision.culling`) skips the pieces out of a camera's view; the images do not change
(tests/test_task.py compares them with ManiSkill's floor).
"""

from __future__ import annotations

import os.path

import numpy as np
import sapien
from mani_skill.utils.building import ground as maniskill_ground

HALF_WIDTH = 50
"""m; ManiSkill's floor is 100 m wide, centred on the robot"""
CENTRE_HALF_WIDTH = 5
"""m; the centre piece, the only one the wrist camera sees"""
TEXTURE = os.path.join(os.path.dirname(maniskill_ground.__file__), "assets", "grid_texture.png")
TEXTURE_SQUARE = 4
"""m per repeat of the texture, as in ManiSkill"""


def build_floor(scene, name: str = "ground"):
    """A static actor `name` with a plane collision at z = 0 and, where the scene renders, the floor's nine
    render bodies (all on the actor's entity: one segmentation id, as ManiSkill's floor has)."""
    builder = scene.create_actor_builder()
    builder.add_plane_collision(sapien.Pose(q=[0.7071068, 0, -0.7071068, 0]))  # the plane's normal along +z
    builder.initial_pose = sapien.Pose()
    if scene.parallel_in_single_scene:
        builder.set_scene_idxs([0])
    actor = builder.build_static(name=name)
    if scene.can_render():
        material = sapien.render.RenderMaterial()
        material.base_color_texture = sapien.render.RenderTexture2D(filename=TEXTURE, mipmap_levels=4)
        edges = (-HALF_WIDTH, -CENTRE_HALF_WIDTH, CENTRE_HALF_WIDTH, HALF_WIDTH)
        pieces = [(x0, x1, y0, y1) for x0, x1 in zip(edges, edges[1:]) for y0, y1 in zip(edges, edges[1:])]
        shapes = [floor_piece(*piece, material) for piece in pieces]
        for entity in actor._objs:
            for shape in shapes:
                body = sapien.render.RenderBodyComponent()
                body.attach(shape)
                entity.add_component(body)
    return actor


def floor_piece(x0: int, x1: int, y0: int, y1: int, material) -> sapien.render.RenderShapeTriangleMesh:
    """The 1 m squares of x0 <= x <= x1, y0 <= y <= y1 (whole metres): each square (x, y) is the triangles
    (x, y) (x+1, y) (x, y+1) and (x+1, y) (x+1, y+1) (x, y+1), texture coordinates x / 4 + 1/2, y / 4 + 1/2."""
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1), indexing="ij")
    vertices = np.stack([xs, ys, np.zeros_like(xs)], -1).reshape(-1, 3).astype(np.float64)
    columns = y1 - y0 + 1
    corner = (np.arange(x1 - x0)[:, None] * columns + np.arange(y1 - y0)[None, :]).ravel()  # (x, y) of each square
    first = np.stack([corner, corner + columns, corner + 1], 1)
    second = np.stack([corner + columns, corner + columns + 1, corner + 1], 1)
    normals = np.zeros_like(vertices)
    normals[:, 2] = 1
    uvs = vertices[:, :2] / TEXTURE_SQUARE + 0.5
    return sapien.render.RenderShapeTriangleMesh(
        vertices=vertices,
        triangles=np.concatenate([first, second]),
        normals=normals,
        uvs=uvs,
        material=material,
    )
