"""View culling for SAPIEN's rasteriser: hide the render bodies a camera cannot see before it captures.

SAPIEN hands the renderer every visible body for every camera; on the software renderer (lavapipe) each
body's triangles are transformed and clipped even when all of them fall outside the image. The wrist
camera never sees most of the robot that carries it (~15,000 triangles) nor most of the floor
(`mani_active_vision.floor`); skipping them cut the wait for its 128² frame from ~5 to ~3 ms (docs/speed.md).
A body is hidden only when its bounding box lies wholly on the outer side of one of the camera's six view
planes (near, far and the four sides, a pixel wider): then none of its triangles can reach a pixel,
so the images are the same as without culling. What a camera hides stays hidden until a capture by a
camera that sees it, or `show_all()` (the task calls it before `render()`).
"""

from __future__ import annotations

import itertools

import numpy as np
import sapien

_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)))  # which of (min, max) each box corner takes per axis


def outside_view(camera: sapien.render.RenderCameraComponent, boxes: np.ndarray) -> np.ndarray:
    """Which of the world-space boxes (N, 2, 3) (min and max corners) lie wholly outside `camera`'s view (N,)."""
    corners = boxes[:, _CORNERS, np.arange(3)]  # (N, 8, 3)
    extrinsic = camera.get_extrinsic_matrix()  # world -> camera, OpenCV axes: x right, y down, z forward
    x, y, z = np.moveaxis(corners @ extrinsic[:, :3].T + extrinsic[:, 3], -1, 0)
    (fx, _, cx), (_, fy, cy), _ = camera.get_intrinsic_matrix()
    width, height = camera.width, camera.height  # with a pixel of margin on every side below
    inside = np.stack(
        [
            z - camera.near,
            camera.far - z,
            fx * x + (cx + 1) * z,  # u = fx x / z + cx >= -1
            (width + 1 - cx) * z - fx * x,  # u <= width + 1
            fy * y + (cy + 1) * z,
            (height + 1 - cy) * z - fy * y,
        ],
        -1,
    )  # (N, 8, 6): >= 0 on the inner side of each plane
    return (inside < 0).all(1).any(-1)


class ViewCuller:
    """Keeps hidden the bodies outside the view of the camera culled for last. Only bodies that cross a view's
    edge change: a change of visibility makes SAPIEN rebuild its object buffers for the next frame, and
    hiding and showing every body around every capture cost about what the hidden triangles saved."""

    def __init__(self):
        self.hidden: dict = {}  # body -> its visibility before it was hidden

    def cull(self, camera: sapien.render.RenderCameraComponent, bodies: list[sapien.render.RenderBodyComponent]):
        """Hide those of `bodies` outside `camera`'s view, show again those of them it hid that are now inside."""
        candidates = [body for body in bodies if body in self.hidden or body.visibility > 0]
        if not candidates:
            return
        outside = outside_view(camera, np.stack([body.get_global_aabb_fast() for body in candidates]))
        for body, out in zip(candidates, outside):
            if out and body not in self.hidden:
                self.hidden[body] = body.visibility
                body.visibility = 0
            elif not out and body in self.hidden:
                body.visibility = self.hidden.pop(body)

    def show_all(self):
        """Show every body this culler hid (before a camera that culls nothing renders, e.g. the human view)."""
        for body, visibility in self.hidden.items():
            body.visibility = visibility
        self.hidden.clear()
