"""Speed of ActiveVisionFind-v0 on this machine: steps/s and where a step's time goes.

Prints, for one env on the CPU: time to the first observation (make + reset), reset time with and without
new objects, steps/s at 128² `rgb+segmentation` and with `state` observations, the split of a step into
controller (IK), physics, render + readback and the rest, and memory growth over repeated reconfigurations.
Timing on shared machines is noisy: compare figures from one run, and see `uptime` below.

    .venv/bin/python baselines/benchmark_env.py
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro

import mani_active_vision as mav
from mani_active_vision.envs import ENV_ID, EnvConfig


@dataclass
class Args:
    steps: int = 300
    """steps per measurement"""
    resets: int = 20
    """resets per reset measurement"""
    reconfigures: int = 200
    """reconfigurations for the memory measurement (0 skips it)"""
    resolution: int = 128


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def timed(owner, name: str, totals: dict):
    """Wrap `owner.name` so that its time adds up in totals[name]."""
    original = getattr(owner, name)

    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            totals[name] += time.perf_counter() - start

    setattr(owner, name, wrapper)


def measure_steps(obs_mode: str, args: Args) -> dict:
    task_kwargs = EnvConfig(start_pose="search", image_size=args.resolution).task_kwargs()
    env = mav.DiscreteDirections(gym.make(ENV_ID, **{**task_kwargs, "obs_mode": obs_mode}, reconfiguration_freq=0))
    base = env.unwrapped
    env.reset(seed=0)
    totals = defaultdict(float)
    timed(base.agent, "set_action", totals)  # controller: closed-form IK + checks + drive targets
    timed(base.scene, "step", totals)  # physics
    timed(base, "_hand_camera_images", totals)  # render + readback of the wrist camera
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 6, size=args.steps)
    start = time.perf_counter()
    for i, a in enumerate(actions):
        env.step(int(a))
        if (i + 1) % 100 == 0:
            env.reset()
    total = time.perf_counter() - start
    env.close()
    ms = {k: 1000 * v / args.steps for k, v in totals.items()}
    ms["total"] = 1000 * total / args.steps
    ms["other"] = ms["total"] - ms["set_action"] - ms["step"] - ms["_hand_camera_images"]
    return dict(steps_per_s=args.steps / total, ms=ms)


def measure_lifecycle(args: Args) -> dict:
    """Time to the first observation (make + reset, shaders compiled), reset times, memory per reconfigure."""
    result = {}
    start = time.perf_counter()
    env = gym.make(ENV_ID, **EnvConfig(image_size=args.resolution).task_kwargs())
    env.reset(seed=0)
    result["first_ready_s"] = time.perf_counter() - start
    base = env.unwrapped
    start = time.perf_counter()
    for i in range(args.resets):
        env.reset(seed=i)
    result["reset_reconfigure_ms"] = 1000 * (time.perf_counter() - start) / args.resets
    base.reconfiguration_freq = 0
    base._reconfig_counter = 0
    start = time.perf_counter()
    for i in range(args.resets):
        env.reset(seed=i)
    result["reset_ms"] = 1000 * (time.perf_counter() - start) / args.resets
    if args.reconfigures:
        for i in range(10):  # warm-up: caches and allocator pools fill on the first reconfigurations
            env.reset(seed=i, options=dict(reconfigure=True))
        before = rss_mb()
        for i in range(args.reconfigures):
            env.reset(seed=i, options=dict(reconfigure=True))
        result["reconfigures"] = args.reconfigures
        result["memory_growth_mb"] = rss_mb() - before
        # The same models every time: what stays is a leak; what grew above was SAPIEN's cache of the
        # distinct meshes loaded so far (bounded by the 800 train models).
        base.placement = "fixed"
        for i in range(10):
            env.reset(seed=i, options=dict(reconfigure=True))
        before = rss_mb()
        for i in range(args.reconfigures):
            env.reset(seed=i, options=dict(reconfigure=True))
        result["memory_growth_same_models_mb"] = rss_mb() - before
    env.close()
    return result


def main(args: Args):
    torch.set_num_threads(1)
    print(f"load average: {os.getloadavg()}")
    life = measure_lifecycle(args)
    print(f"first make + reset: {life['first_ready_s']:.2f} s")
    print(f"reset with new objects (reconfigure): {life['reset_reconfigure_ms']:.1f} ms")
    print(f"reset without reconfigure: {life['reset_ms']:.1f} ms")
    if args.reconfigures:
        print(
            f"memory: +{life['memory_growth_mb']:.1f} MB after {args.reconfigures} reconfigures with new objects "
            f"({life['memory_growth_mb'] / args.reconfigures * 1000:.0f} kB each), "
            f"+{life['memory_growth_same_models_mb']:.1f} MB after {args.reconfigures} with the same models"
        )
    print()
    print(f"| obs_mode ({args.resolution}²) | steps/s | controller ms | physics ms | render+readback ms | other ms |")
    print("|---|---|---|---|---|---|")
    for mode in ("rgb+segmentation", "state"):
        r = measure_steps(mode, args)
        m = r["ms"]
        print(
            f"| {mode} | {r['steps_per_s']:.0f} | {m['set_action']:.2f} | {m['step']:.2f} | {m['_hand_camera_images']:.2f} | {m['other']:.2f} |"
        )
    print("\n`state` still renders the wrist camera's segmentation: the reward is the target's share of the image.")
    print(f"load average: {os.getloadavg()}")


if __name__ == "__main__":
    main(tyro.cli(Args))
