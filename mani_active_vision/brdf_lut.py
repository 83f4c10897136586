"""The renderer's BRDF lookup table, computed once per machine instead of once per process.

SAPIEN's renderer (svulkan2) samples a split-sum BRDF table (`samplerBRDFLUT`, the image-based-lighting
term of the "minimal" shader: u = roughness, v = n·v) and, when none is supplied, generates it with a
compute shader on the first picture of every process. On lavapipe (software Vulkan) that one dispatch
costs ~14 s of CPU here, most of a first `make` + `reset` ("shader compilation" was a misnomer: with Mesa's
shader cache on or off the time is the same). Supplying the table as the camera texture `BRDFLUT` skips
it. The table is the standard split-sum integral (Karis 2013; the svulkan2 docstring points to
learnopengl.com's "Specular IBL"), computed here in numpy and shipped as `assets/brdf_lut_128.npy`
(regenerate with `python -m mani_active_vision.brdf_lut`). In this task's scenes the table does not change
a single pixel (measured: the default, this table and its transpose give identical images), so the saving
costs nothing; a scene with an environment map would use it.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

SIZE = 128
SAMPLES = 1024
ASSET = Path(__file__).parent / "assets" / f"brdf_lut_{SIZE}.npy"


def _radical_inverse(i: np.ndarray) -> np.ndarray:
    """Van der Corput sequence in base 2 (bit reversal of a 32-bit integer), in [0, 1)."""
    bits = i.astype(np.uint32)
    bits = ((bits << 16) | (bits >> 16)).astype(np.uint32)
    for shift, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
        bits = (((bits & mask) << shift) | ((bits & ~np.uint32(mask)) >> shift)).astype(np.uint32)
    return bits.astype(np.float64) * 2.3283064365386963e-10


def compute_brdf_lut(size: int = SIZE, samples: int = SAMPLES) -> np.ndarray:
    """(size, size, 2) float32: scale and bias of F0 in the split-sum specular term, rows = n·v,
    columns = roughness, at texel centres; importance-sampled GGX, Smith geometry with k = roughness²/2."""
    centres = (np.arange(size) + 0.5) / size
    roughness = centres[:, None]  # columns
    i = np.arange(samples)
    xi_x, xi_y = i / samples, _radical_inverse(i)
    a = roughness**2
    cos_theta = np.sqrt((1 - xi_y) / (1 + (a * a - 1) * xi_y))  # (size, samples)
    h_x, h_z = np.cos(2 * np.pi * xi_x) * np.sqrt(1 - cos_theta**2), cos_theta  # half vector; its y never enters
    k = roughness**2 / 2
    table = np.empty((size, size, 2), np.float32)
    for row, n_dot_v in enumerate(centres):  # one row at a time keeps memory small
        v_x, v_z = np.sqrt(1 - n_dot_v**2), n_dot_v  # view vector in the x-z plane, normal = z
        v_dot_h = v_x * h_x + v_z * h_z
        n_dot_l = np.maximum(2 * v_dot_h * h_z - v_z, 0)
        v_dot_h = np.maximum(v_dot_h, 0)
        geometry = (n_dot_v / (n_dot_v * (1 - k) + k)) * (n_dot_l / (n_dot_l * (1 - k) + k))
        visibility = np.where(n_dot_l > 0, geometry * v_dot_h / (np.maximum(h_z, 0) * n_dot_v), 0.0)
        fresnel = (1 - v_dot_h) ** 5
        table[row, :, 0] = ((1 - fresnel) * visibility).mean(-1)
        table[row, :, 1] = (fresnel * visibility).mean(-1)
    return table


@cache
def brdf_lut_array() -> np.ndarray:
    """The shipped table (computed if the file is missing)."""
    try:
        return np.load(ASSET)
    except OSError:
        return compute_brdf_lut()


@cache
def _brdf_lut_texture():
    import sapien

    return sapien.render.RenderTexture(brdf_lut_array(), 2, "R32G32Sfloat", 1, "linear", "edge")


def supply_brdf_lut(cameras) -> None:
    """Give each ManiSkill camera (its SAPIEN camera components) the table, before its first picture."""
    texture = _brdf_lut_texture()
    for camera in cameras:
        for component in camera.camera._render_cameras:
            component.set_texture("BRDFLUT", texture)


if __name__ == "__main__":
    ASSET.parent.mkdir(exist_ok=True)
    np.save(ASSET, compute_brdf_lut())
    print(f"wrote {ASSET}")
