"""The main job (first version): a scripted search in ActiveVisionFind-v0.

Orbits left from the search pose until the target is seen, then centres its ground-truth box (orbit for
x, up/down for y) and steps forward (zooms in); prints what it saw and writes a PNG of the wrist view
beside the target image to outputs/.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from PIL import Image

import mani_active_vision as mav


@dataclass
class Args:
    seed: int = 0
    out_dir: str = "outputs"


def servo_direction(box, sweep: str) -> str:
    x, y, w, h = box
    if w == 0:
        return sweep  # not seen: orbit
    cx, cy = x + w / 2, y + h / 2
    if abs(cx - 0.5) > 0.1:
        return "left" if cx < 0.5 else "right"
    if abs(cy - 0.5) > 0.1:
        return "up" if cy < 0.5 else "down"  # raising the camera moves the object down the image
    return "forward"


def main(args: Args):
    torch.set_num_threads(1)
    env = mav.DiscreteDirections(gym.make("ActiveVisionFind-v0", obs_mode="rgb+segmentation", render_backend="cpu", start_pose="search"))
    obs, info = env.reset(seed=args.seed)
    print(f"objects: {env.unwrapped.object_names[0]} (target: {env.unwrapped.object_names[0][0]})")
    sweep = "left"
    for step in range(100):
        action = mav.DIRECTIONS.index(servo_direction(info["target_bbox"][0].tolist(), sweep))
        obs, reward, terminated, truncated, info = env.step(action)
        if bool(info["refused"][0]):  # at a limit (joint 1 at ±170°, the workspace): sweep back
            sweep = "right" if sweep == "left" else "left"
        if step % 10 == 0 or bool(info["success"][0]):
            print(f"step {step:3d} {mav.DIRECTIONS[action]:8s} target share {float(reward[0]):.3f} visible {bool(info['target_visible'][0])}")
        if bool(info["success"][0]):
            break
    os.makedirs(args.out_dir, exist_ok=True)
    view = obs["sensor_data"]["hand_camera"]["rgb"][0].numpy()
    target = np.array(Image.fromarray(obs["extra"]["target_image"][0].numpy()).resize(view.shape[:2][::-1]))
    path = os.path.join(args.out_dir, "demo_view.png")
    Image.fromarray(np.concatenate([view, target], 1)).save(path)
    print(f"success: {bool(info['success'][0])}; wrist view | target image written to {path}")
    env.close()


if __name__ == "__main__":
    main(tyro.cli(Args))
