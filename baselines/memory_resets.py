"""Memory over many resets: the process's resident memory (RSS) every 100 resets of the project's env.

Every reset builds a new scene (as `make_env` does). With the same models each time (`placement="fixed"`:
the same scene), memory that grows is a leak; with new objects (`placement="random"`) SAPIEN also caches
each distinct mesh it loads (bounded by the 800 train models). 20 resets of warm-up come first (two of the
task's periodic full garbage collections, `ActiveVisionFindEnv.collect_every`).

    .venv/bin/python baselines/memory_resets.py --resets 1000
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import torch
import tyro

import mani_active_vision as mav


@dataclass
class Args:
    resets: int = 1000
    placements: tuple[str, ...] = ("fixed", "random")
    """fixed: the same models every reset (a leak shows); random: new objects"""
    every: int = 100
    """print RSS every this many resets"""


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(placement: str, resets: int, every: int = 100) -> dict:
    """RSS (MB) after the warm-up and after every `every` resets, and ms per reset."""
    env = mav.make_env(mav.EnvConfig(placement=placement, image_size=128, box_source="none"))
    for seed in range(20):
        env.reset(seed=seed)
    curve = [rss_mb()]
    start = time.perf_counter()
    for i in range(resets):
        env.reset(seed=20 + i)
        if (i + 1) % every == 0:
            curve.append(rss_mb())
    reset_ms = 1000 * (time.perf_counter() - start) / resets
    env.close()
    return dict(placement=placement, resets=resets, rss_mb=curve, growth_mb=curve[-1] - curve[0], reset_ms=reset_ms)


def main(args: Args):
    torch.set_num_threads(1)
    for placement in args.placements:
        print(f"load average {os.getloadavg()[0]:.2f}")
        r = measure(placement, args.resets, args.every)
        print(
            f"placement={placement}: RSS {r['rss_mb'][0]:.0f} MB after warm-up, {r['rss_mb'][-1]:.0f} MB after "
            f"{args.resets} resets ({r['growth_mb']:+.1f} MB); {r['reset_ms']:.0f} ms per reset; every {args.every}: "
            + " ".join(f"{x:.0f}" for x in r["rss_mb"])
        )


if __name__ == "__main__":
    main(tyro.cli(Args))
