"""Speed of ActiveVisionFind-v0 against the paper's PyBullet setup, everything in one run (docs/speed.md).

Every rate is taken in rounds: each round steps every subject in turn for `--steps` steps, so that the
load of a shared machine (printed with each round) falls alike on all of them, and every ratio compares
rates taken side by side. Subjects:
- the reference: the paper's setup rebuilt in PyBullet (`pybullet_reference.py`), at 128² and 256²;
- our task, one env (`make_env`: new objects every episode, like the reference), 128² and 256²
  rgb+segmentation, at 128² also with the wrist camera on SAPIEN's `minimal` shader pack (before
  `mani_active_vision.wrist_shader`), and with `state` observations (the reward still renders the segmentation);
- the agent loop: the env with the FCN's box (`box_source="fcn"`) and a Q-network choosing the actions, with the
  network segmenting at its 64² and at the camera's 128² (`envs.FCN_SEGMENT_SIZE`, as the shipped DQN is deployed);
- 1, 2 and 4 worker processes (`make_vec_env`, 128²) with their share of the cores and pinned to them
  (`mani_active_vision.threads`); 2 not pinned (`pin_workers=False`); and 1 and 2 as before issue 14: lavapipe's
  default of a render thread per core (`LP_NUM_THREADS` = cores), not pinned.
Then: the first env ready in a fresh process, reset times, and RSS over `--resets` resets with the same
models (`memory_resets.py`). Writes benchmark.md and benchmark.json to `--out`.

    .venv/bin/python baselines/benchmark.py     # ~6 min on a 2-core machine
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import memory_resets
import numpy as np
import pybullet_reference
import torch
import tyro

import mani_active_vision as mav
from mani_active_vision.agents.q_network import QNetwork
from mani_active_vision.envs import ENV_ID, FCN_SEGMENT_SIZE, EnvConfig, make_env, wrap_env
from mani_active_vision.json_io import save_json
from mani_active_vision.threads import available_cores
from mani_active_vision.vec_env import make_vec_env


@dataclass
class Args:
    rounds: int = 3
    """rounds of interleaved measurements"""
    steps: int = 100
    """steps per subject per round (per worker for the worker pools)"""
    resolutions: tuple[int, ...] = (128, 256)
    workers: tuple[int, ...] = (1, 2, 4)
    """worker-process counts (128²)"""
    unpinned_workers: tuple[int, ...] = (2,)
    """worker-process counts also measured not pinned to their cores"""
    default_threads_workers: tuple[int, ...] = (1, 2)
    """worker-process counts also measured with lavapipe's default threads, not pinned"""
    resets: int = 1000
    """resets with the same models for the memory measurement (0 skips it)"""
    fcn_weights: str = ""
    """an FCN checkpoint for the agent loop's rows ("": the shipped one, `agents/weights/fcn.pt`)"""
    gpu_envs: tuple[int, ...] = (64, 256, 1024)
    """num_envs for the GPU backend (measured only when CUDA is available)"""
    out: Path = field(default_factory=lambda: Path("outputs/benchmark"))


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


class Single:
    """One env stepped with random directions (or a policy), reset at the end of each episode."""

    def __init__(self, env, reset_every: int | None = None, policy=None):
        self.env, self.reset_every, self.policy = env, reset_every, policy
        self.rng = np.random.default_rng(0)
        self.obs = env.reset(seed=0)
        self.obs = self.obs[0] if isinstance(self.obs, tuple) else self.obs
        self.count, self.num_envs = 0, 1

    def run(self, steps: int):
        for _ in range(steps):
            action = int(self.rng.integers(len(mav.DIRECTIONS)))
            if self.policy is not None and self.rng.random() > 0.1:  # the agent loop: the Q-network acts
                with torch.no_grad():
                    action = int(self.policy(torch.as_tensor(self.obs, dtype=torch.float32)).argmax())
            out = self.env.step(action)
            self.obs, self.count = out[0], self.count + 1
            ended = out[2] or out[3] if len(out) == 5 else self.count % self.reset_every == 0
            if ended:
                reset = self.env.reset()
                self.obs = reset[0] if isinstance(reset, tuple) else reset

    def close(self):
        self.env.close()


class Pool:
    """A vector env stepped with random directions (it resets finished episodes itself)."""

    def __init__(self, env):
        self.env, self.num_envs = env, env.num_envs
        self.rng = np.random.default_rng(0)
        env.reset(seed=0)

    def run(self, steps: int):
        for _ in range(steps):
            self.env.step(self.rng.integers(len(mav.DIRECTIONS), size=self.num_envs))

    def close(self):
        self.env.close()


def make_pool(num_workers: int, lavapipe_default: bool = False, pin: bool = True) -> Pool:
    config = EnvConfig(start_pose="search", image_size=128, box_source="none")
    if not lavapipe_default:
        return Pool(make_vec_env(config, num_workers, backend="cpu", pin_workers=pin))
    os.environ["LP_NUM_THREADS"] = str(available_cores())  # a user's setting: it wins over the share
    try:
        return Pool(make_vec_env(config, num_workers, backend="cpu", pin_workers=pin))
    finally:
        del os.environ["LP_NUM_THREADS"]


def minimal_shader_env(config: EnvConfig) -> gym.Env:
    """`make_env(config)` with the wrist camera on SAPIEN's two-pass `minimal` pack (the same images)."""
    kwargs = config.task_kwargs()
    kwargs["sensor_configs"]["hand_camera"]["shader_pack"] = "minimal"  # ManiSkill's way to choose a shader
    return wrap_env(gym.make(ENV_ID, **kwargs), config)


def subjects(args: Args) -> dict:
    """name -> (how to make it, reference name or None)"""
    ours = lambda size, **kw: EnvConfig(start_pose="search", image_size=size, **kw)
    table = {}
    for size in args.resolutions:
        table[f"PyBullet reference, {size}²"] = (
            lambda size=size: Single(pybullet_reference.PyBulletReference(size), reset_every=100),
            None,
        )
    for size in args.resolutions:
        table[f"ours, 1 env, {size}² rgb+segmentation"] = (
            lambda size=size: Single(make_env(ours(size, box_source="none"))),
            f"PyBullet reference, {size}²",
        )
    table["ours, 1 env, 128², the wrist camera on SAPIEN's `minimal` shader pack"] = (
        lambda: Single(minimal_shader_env(ours(128, box_source="none"))),
        "PyBullet reference, 128²",
    )
    table["ours, 1 env, state (128² segmentation for the reward)"] = (
        lambda: Single(mav.DiscreteDirections(gym.make(ENV_ID, **{**ours(128).task_kwargs(), "obs_mode": "state"}))),
        "PyBullet reference, 128²",
    )
    table["ours, 1 env, render-free box state (the target's hull projected)"] = (
        lambda: Single(make_env(ours(128, box_source="projection"))),
        "PyBullet reference, 128²",
    )
    table["agent loop: 1 env, 128² + FCN box + Q-network"] = (
        lambda: Single(make_env(ours(128, box_source="fcn", fcn_weights=args.fcn_weights)), policy=QNetwork(4)),
        "PyBullet reference, 128²",
    )
    table["agent loop, the FCN segmenting at 128² (as the shipped DQN is deployed)"] = (
        lambda: Single(
            make_env(ours(128, box_source="fcn", fcn_segment_size=FCN_SEGMENT_SIZE, fcn_weights=args.fcn_weights)),
            policy=QNetwork(4),
        ),
        "PyBullet reference, 128²",
    )
    for n in args.workers:
        table[f"ours, {n} worker(s), 128² (total)"] = (lambda n=n: make_pool(n), "ours, 1 worker(s), 128² (total)")
    for n in args.unpinned_workers:
        table[f"ours, {n} worker(s), not pinned (total)"] = (
            lambda n=n: make_pool(n, pin=False),
            "ours, 1 worker(s), 128² (total)",
        )
    for n in args.default_threads_workers:
        table[f"ours, {n} worker(s), lavapipe's default threads, not pinned (total)"] = (
            lambda n=n: make_pool(n, lavapipe_default=True, pin=False),
            "ours, 1 worker(s), lavapipe's default threads, not pinned (total)",
        )
    return table


FIRST_ENV = """
import json, time
start = time.perf_counter()
import mani_active_vision as mav
imported = time.perf_counter()
env = mav.make_env(mav.EnvConfig(image_size=128))
env.reset(seed=0)
ready = time.perf_counter()
for seed in range(20):
    env.reset(seed=seed)
new_objects = time.perf_counter()
env.unwrapped.reconfiguration_freq = 0
for seed in range(20):
    env.reset(seed=seed)
same = time.perf_counter()
print(json.dumps(dict(import_s=imported - start, first_ready_s=ready - imported, reset_new_objects_ms=50 * (new_objects - ready),
                      reset_ms=50 * (same - new_objects))))
"""


def first_env() -> dict:
    """Import, first make + reset and reset times, in a fresh process (nothing compiled or cached yet)."""
    out = subprocess.run([sys.executable, "-c", FIRST_ENV], capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(args: Args):
    torch.set_num_threads(1)
    lines = [
        f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {os.cpu_count()} CPU cores "
        f"({platform.processor() or platform.machine()}), "
        f"{'GPU: ' + torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'}; "
        f"{args.rounds} rounds x {args.steps} steps per subject, interleaved"
        f"{'; the agent loop on ' + args.fcn_weights if args.fcn_weights else ''}.",
        "",
    ]
    log = lambda text: (print(text, flush=True), lines.append(text))
    log(f"load average (1/5/15 min) at start: {load()}")
    start = time.perf_counter()
    life = first_env()
    log(
        f"first env ready (fresh process, make + reset): {life['first_ready_s']:.2f} s after {life['import_s']:.2f} s "
        f"of imports; reset with new objects {life['reset_new_objects_ms']:.0f} ms, without {life['reset_ms']:.0f} ms "
        f"(load {load()})"
    )
    table = subjects(args)
    made = {}
    for name, (make, _) in table.items():
        began = time.perf_counter()
        made[name] = make()
        log(f"made {name} in {time.perf_counter() - began:.1f} s (load {load()})")
    rates = {name: [] for name in made}
    for r in range(args.rounds):
        for name, subject in made.items():
            subject.run(5)  # warm-up after the other subjects ran
            began = time.perf_counter()
            subject.run(args.steps)
            rates[name].append(args.steps * subject.num_envs / (time.perf_counter() - began))
        log(f"round {r + 1}: load {load()}")
    for subject in made.values():
        subject.close()
    mean = {name: float(np.mean(v)) for name, v in rates.items()}
    lines += [
        "",
        "| what | steps/s (mean of rounds) | rounds' min-max | × reference (in the same rounds) |",
        "|---|---|---|---|",
    ]
    for name, (_, ref) in table.items():
        ratio = f"{np.mean(np.array(rates[name]) / np.array(rates[ref])):.2f}× {ref}" if ref else "reference"
        lines.append(f"| {name} | {mean[name]:.0f} | {min(rates[name]):.0f}-{max(rates[name]):.0f} | {ratio} |")
    if torch.cuda.is_available():
        for n in args.gpu_envs:
            pool = Pool(make_vec_env(EnvConfig(image_size=128, box_source="none"), n, backend="gpu"))
            began = time.perf_counter()
            pool.run(args.steps)
            lines.append(
                f"| ours, GPU backend, {n} envs (total) | {args.steps * n / (time.perf_counter() - began):.0f} | | |"
            )
    memory = None
    if args.resets:
        memory = memory_resets.measure("fixed", args.resets)
        lines.append(
            f"\nRSS over {args.resets} resets with the same models (new scene each): {memory['rss_mb'][0]:.0f} -> "
            f"{memory['rss_mb'][-1]:.0f} MB ({memory['growth_mb']:+.1f} MB), {memory['reset_ms']:.0f} ms per reset; "
            f"every 100: {' '.join(f'{x:.0f}' for x in memory['rss_mb'])} (load {load()})"
        )
    lines.append(f"\nload average at the end: {load()}; {time.perf_counter() - start:.0f} s in all")
    report = "\n".join(lines)
    print(
        "\n"
        + "\n".join(
            lines[
                lines.index("| what | steps/s (mean of rounds) | rounds' min-max | × reference (in the same rounds) |")
                - 1 :
            ]
        )
    )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "benchmark.md").write_text(report + "\n")
    record = dict(
        rates=rates,
        first_env=life,
        memory=memory,
        cpu_count=os.cpu_count(),
        args={k: str(v) for k, v in vars(args).items()},
    )
    save_json(record, str(args.out / "benchmark.json"))
    print(f"\nwrote {args.out / 'benchmark.md'} and {args.out / 'benchmark.json'}")


if __name__ == "__main__":
    main(tyro.cli(Args))
