"""Speed of ActiveVisionFind-v0 against the paper's PyBullet environment, measured in one run (docs/design.md §12).

Steps/s of: our task, one env, at 128² and 256² `rgb+segmentation` and with `state` observations; the
PyBullet reference (`pybullet_reference.py`) at the same sizes; 1 and 2 worker processes
(`make_vec_env`, 128² rgb+segmentation); one env with the FCN box state.
Also time to the first observation, resets and memory growth over reconfigurations
(`benchmark_env.py`). Ratios are to the reference measured in the same run (timings on a shared machine
are noisy; the load average is recorded). Writes a markdown table and JSON to `--out`.

    .venv/bin/python baselines/benchmark.py     # ~5 min on an idle 2-core machine (estimated); 15 min at load 15
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path

import benchmark_env
import numpy as np
import pybullet_reference
import torch
import tyro
from tqdm import tqdm

import mani_active_vision as mav
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.json_io import save_json
from mani_active_vision.vec_env import make_vec_env


@dataclass
class Args:
    steps: int = 300
    """steps per measurement (per worker for the worker pools)"""
    resolutions: tuple[int, ...] = (128, 256)
    """camera image sides to compare with the reference"""
    workers: tuple[int, ...] = (1, 2)
    """worker-process counts for the batched measurement (128²)"""
    reconfigures: int = 300
    """reconfigurations for the memory measurement (0 skips it)"""
    gpu_envs: tuple[int, ...] = (64, 256, 1024)
    """num_envs for the GPU backend (measured only when CUDA is available)"""
    out: Path = field(default_factory=lambda: Path("outputs/benchmark"))
    """folder for benchmark.md and benchmark.json"""


def time_steps(env, steps: int, num_envs: int | None = None, seed: int = 0) -> float:
    """Steps/s (summed over envs) of random directions; a vector env autoresets, a single env is reset every 100 steps."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    start = time.perf_counter()
    for i in range(steps):
        if num_envs is None:
            env.step(int(rng.integers(len(mav.DIRECTIONS))))
            if (i + 1) % 100 == 0:
                env.reset()
        else:
            env.step(rng.integers(len(mav.DIRECTIONS), size=num_envs))
    return steps * (num_envs or 1) / (time.perf_counter() - start)


def measure_workers(num_workers: int, steps: int) -> dict:
    start = time.perf_counter()
    env = make_vec_env(EnvConfig(start_pose="search", image_size=128, box_source="none"), num_workers, backend="cpu")
    env.reset(seed=0)
    ready = time.perf_counter() - start
    try:
        return dict(steps_per_s=time_steps(env, steps, num_workers), pool_ready_s=ready)
    finally:
        env.close()


def measure_fcn(steps: int) -> float:
    env = make_env(EnvConfig(start_pose="search", image_size=128, box_source="fcn"))
    try:
        return time_steps(env, steps)
    finally:
        env.close()


def measure_gpu(num_envs: int, steps: int) -> float:
    env = make_vec_env(EnvConfig(start_pose="search", image_size=128, box_source="none"), num_envs, backend="gpu")
    try:
        return time_steps(env, steps, num_envs)
    finally:
        env.close()


def main(args: Args):
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    env_args = lambda resolution: benchmark_env.Args(
        steps=args.steps, resolution=resolution, reconfigures=args.reconfigures
    )
    rows = []  # (what, steps/s, reference key or None)
    jobs = [
        "lifecycle",
        *[f"ours {r}" for r in args.resolutions],
        "ours state",
        *[f"pybullet {r}" for r in args.resolutions],
        *[f"workers {n}" for n in args.workers],
        "fcn",
    ]
    results: dict = {}
    progress = tqdm(jobs, desc="benchmark")
    for job in progress:
        progress.set_postfix_str(job)
        kind, _, value = job.partition(" ")
        if kind == "lifecycle":  # first: the first env of the run is the one that compiles the shaders
            results["lifecycle"] = benchmark_env.measure_lifecycle(env_args(128))
        elif kind == "ours" and value == "state":
            results[job] = benchmark_env.measure_steps("state", env_args(128))
            rows.append(
                ("ours, 1 env, state (128² segmentation for the reward)", results[job]["steps_per_s"], "pybullet 128")
            )
        elif kind == "ours":
            results[job] = benchmark_env.measure_steps("rgb+segmentation", env_args(int(value)))
            rows.append((f"ours, 1 env, {value}² rgb+segmentation", results[job]["steps_per_s"], f"pybullet {value}"))
        elif kind == "pybullet":
            results[job] = dict(steps_per_s=pybullet_reference.steps_per_second(int(value), args.steps))
            rows.append((f"PyBullet reference, {value}² rgb+segmentation", results[job]["steps_per_s"], None))
        elif kind == "workers":
            results[job] = measure_workers(int(value), args.steps)
            rows.append(
                (
                    f"ours, {value} worker process(es), 128² rgb+segmentation (total)",
                    results[job]["steps_per_s"],
                    "pybullet 128",
                )
            )
        elif kind == "fcn":
            results[job] = dict(steps_per_s=measure_fcn(args.steps))
            rows.append(("ours, 1 env, 128² + FCN box state", results[job]["steps_per_s"], "pybullet 128"))
    if torch.cuda.is_available():
        for n in args.gpu_envs:
            results[f"gpu {n}"] = dict(steps_per_s=measure_gpu(n, args.steps))
            rows.append(
                (
                    f"ours, GPU backend, {n} envs, 128² rgb+segmentation (total)",
                    results[f"gpu {n}"]["steps_per_s"],
                    "pybullet 128",
                )
            )

    life = results["lifecycle"]
    lines = [
        f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {os.cpu_count()} CPU cores ({platform.processor() or platform.machine()}), "
        f"{'GPU: ' + torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'}; "
        f"load average {load_before[0]:.1f} before, {os.getloadavg()[0]:.1f} after; {args.steps} steps per measurement.",
        "",
        "| what | steps/s | × PyBullet |",
        "|---|---|---|",
    ]
    for what, rate, ref in rows:
        ratio = "1" if ref is None else f"{rate / results[ref]['steps_per_s']:.2f}" if ref in results else "–"
        lines.append(f"| {what} | {rate:.0f} | {ratio} |")
    if all(f"workers {n}" in results for n in (1, 2)):
        scaling = results["workers 2"]["steps_per_s"] / results["workers 1"]["steps_per_s"]
        lines.append(
            f"\n2 workers / 1 worker: {scaling:.2f}×; pool ready (start + reset): "
            + ", ".join(f"{n} worker(s) {results[f'workers {n}']['pool_ready_s']:.1f} s" for n in args.workers)
        )
    lines.append(
        f"First env ready (make + reset, shaders compiled): {life['first_ready_s']:.2f} s; "
        f"reset {life['reset_ms']:.1f} ms, with new objects {life['reset_reconfigure_ms']:.1f} ms."
    )
    if "memory_growth_mb" in life:
        lines.append(
            f"Memory over {life['reconfigures']} reconfigures: +{life['memory_growth_mb']:.1f} MB with new objects "
            f"(SAPIEN caching each distinct mesh; bounded by the 800 train models), "
            f"+{life['memory_growth_same_models_mb']:.1f} MB with the same models (≈ "
            f"{life['memory_growth_same_models_mb'] / life['reconfigures'] * 1000:.1f} MB per 1,000: the leak)."
        )
    split = results.get("ours 128", {}).get("ms")
    if split:
        lines.append(
            f"One 128² step: controller {split['set_action']:.2f} ms, physics {split['step']:.2f} ms, "
            f"render + readback {split['_hand_camera_images']:.2f} ms, other {split['other']:.2f} ms."
        )
    if not torch.cuda.is_available():
        lines.append("GPU backend: not measured (no CUDA device on this machine).")
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "benchmark.md").write_text(table + "\n")
    record = dict(
        results=results,
        load_average_before=load_before,
        load_average_after=os.getloadavg(),
        cpu_count=os.cpu_count(),
        cuda=torch.cuda.is_available(),
        args={k: str(v) for k, v in vars(args).items()},
    )
    save_json(record, str(args.out / "benchmark.json"))
    print(f"\nwrote {args.out / 'benchmark.md'} and {args.out / 'benchmark.json'}")


if __name__ == "__main__":
    main(tyro.cli(Args))
