"""The wrist camera's shader: SAPIEN's `minimal` pack less the work that adds nothing to this task's images.

`minimal` draws a frame in two passes: `gbuffer.frag` lights each covered pixel (ambient light, the scene's
lights, and an image-based term that samples the environment cube map twice and the BRDF table), then
`composite0.frag` goes over every pixel again to put the environment map behind what was drawn. In this
task neither adds anything to the wrist camera's images: its scenes have no environment map (ManiSkill's
default lighting: ambient and two directional lights), so the image-based term is exactly zero, and the
camera always looks down at the floor (60° down with a 70° field of view: its highest ray meets the floor
within ~3 m), so nothing is ever behind. On a software rasteriser each pass costs per pixel (lavapipe JIT
compiles the shaders; texture sampling is what it pays most for).

The pack here is derived from the installed SAPIEN's `minimal` when first asked for (nothing of SAPIEN's is
copied into the project): the image-based lines removed and the lit colour written as the final `Color`, in one
pass. It is written once per user and SAPIEN version to a folder of the system's temporary directory named by
its contents, which every process then reuses (worker processes exit without clean-up: a folder per process
would pile up). The images are bit-identical (`tests/test_task.py` renders with `minimal` beside it); the frame
costs ~0.9 ms less at 128² (docs/speed.md). Where the installed SAPIEN's sources differ from what is expected,
or the folder cannot be written, the wrist camera keeps `minimal` and a warning says so.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import warnings
from functools import cache
from pathlib import Path

import sapien
from mani_skill.render.shaders import PREBUILT_SHADER_CONFIGS, ShaderConfig

MINIMAL = Path(sapien.__file__).parent / "vulkan_shader" / "minimal"
IMAGE_BASED_LIGHTING = """  color += diffuseIBL(diffuseAlbedo, wnormal);
  color += specularIBL(fresnel, roughness,
                       wnormal,
                       mat3(cameraBuffer.viewMatrixInverse) * camDir);
"""
COMPOSITED_OUTPUT = "outColorRaw"
FINAL_OUTPUT = "outColor"  # the pack's last pass writes the camera's `Color` texture
INCLUDE = '#include "../common/'


@cache
def derived_pack() -> Path | None:
    """The folder of the one-pass pack; None where SAPIEN's `minimal` is not the version this was derived from or
    the folder cannot be written."""
    gbuffer = (MINIMAL / "gbuffer.frag").read_text()
    if IMAGE_BASED_LIGHTING not in gbuffer or gbuffer.count(COMPOSITED_OUTPUT) != 2:
        warnings.warn(
            f"{MINIMAL / 'gbuffer.frag'} is not the version mani_active_vision.wrist_shader expects; the wrist "
            "camera uses SAPIEN's 'minimal' shader pack (the same images, ~0.9 ms slower per frame)",
            stacklevel=2,
        )
        return None
    gbuffer = gbuffer.replace(IMAGE_BASED_LIGHTING, "").replace(COMPOSITED_OUTPUT, FINAL_OUTPUT)
    gbuffer = gbuffer.replace(INCLUDE, f'#include "{MINIMAL.parent / "common"}/')
    files = {
        "gbuffer.frag": gbuffer,
        **{name: (MINIMAL / name).read_text() for name in ("gbuffer.vert", "shadow.vert")},
    }
    digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / f"mani_active_vision_shader_{os.getuid()}_{digest}"
    if _holds(folder, files):
        return folder
    try:
        staging = Path(tempfile.mkdtemp(prefix=f"{folder.name}_", dir=folder.parent))
        for name, text in files.items():
            (staging / name).write_text(text)
    except OSError as error:
        warnings.warn(f"the wrist camera uses SAPIEN's 'minimal' shader pack: {error}", stacklevel=2)
        return None
    try:
        staging.rename(folder)  # atomic: where another process made it first, this fails and theirs is used
    except OSError:
        if _holds(folder, files):
            shutil.rmtree(staging, ignore_errors=True)
            return folder
        atexit.register(shutil.rmtree, staging, ignore_errors=True)  # someone else's folder: a private one
        return staging
    return folder


def _holds(folder: Path, files: dict[str, str]) -> bool:
    """Whether `folder` is this user's and holds exactly `files`."""
    try:
        return folder.stat().st_uid == os.getuid() and all((folder / n).read_text() == t for n, t in files.items())
    except OSError:
        return False


def wrist_shader_config() -> ShaderConfig:
    """The wrist camera's `ShaderConfig`: the one-pass pack, read as `minimal` is (8-bit colour; position and
    segmentation in one texture)."""
    minimal = PREBUILT_SHADER_CONFIGS["minimal"]
    folder = derived_pack()
    if folder is not None and not folder.exists():  # the temporary directory was cleaned while this process ran
        derived_pack.cache_clear()
        folder = derived_pack()
    if folder is None:
        return minimal
    # ManiSkill sets these formats only for packs named "minimal"; they are global, read when a camera is made.
    sapien.render.set_picture_format("Color", "r8g8b8a8unorm")
    sapien.render.set_picture_format("PositionSegmentation", "r16g16b16a16sint")
    return ShaderConfig(str(folder), minimal.texture_names, texture_transforms=minimal.texture_transforms)
