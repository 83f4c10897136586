"""FCN latency: milliseconds per wrist frame on one CPU thread, batch 1 and 8, through `predict` (uint8 in,
bool mask out, resizing included when the frame size differs from the training size), with each runtime:
"torch" (the model run eagerly) and "onnxruntime" (the same graph exported from it, `predict`'s default on
the CPU). Two cases: the same target image at every call (an episode: `predict` computes the target's
features once and reuses them) and a new target image at every call.

The machine is shared, so timings are noisy: the runtimes are timed in alternating blocks of calls (the
same load for both), medians and minima are printed, with the load average, and, as a reference measured
in the same run, the env's own step time at the same frame size (rgb+segmentation). Last, `predict` timed
where it runs: inside the steps of the project's env with the FCN box state (`BoxState`, batch 1, random
directions), where rendering has just filled the caches with other data. With a verifier, a third runtime,
"onnxruntime, verifier on torch", runs the network on ONNX Runtime and the verifier in torch (how `predict`
ran before the verifier went to ONNX Runtime too).

  python baselines/benchmark_fcn.py                      # 128² (the env's default) and 64²
"""

from __future__ import annotations

import copy
import functools
import itertools
import os
import time
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch
import tyro

import mani_active_vision  # noqa: F401  (registers the task)
from mani_active_vision.agents.fcn import WEIGHTS_PATH, load_checkpoint, segmenting_at
from mani_active_vision.envs import ENV_ID, EnvConfig, make_env


@dataclass
class Args:
    weights: str | None = None
    """FCN checkpoint (default: the shipped agents/weights/fcn.pt)"""
    sizes: list[int] = field(default_factory=lambda: [128, 64])
    """wrist frame sides to time"""
    batch_sizes: list[int] = field(default_factory=lambda: [1, 8])
    repeats: int = 50
    """timed calls per setting (after 5 warm-up calls)"""
    env_reference: bool = True
    """also time env.step at each size (the reference)"""
    runtimes: list[str] = field(default_factory=lambda: ["torch", "onnxruntime"])
    """`predict`'s runtimes to compare"""
    verifier_on_torch: bool = True
    """with a verifier, also time "onnxruntime" with the verifier run by torch"""
    largest_component: bool = True
    """keep each mask's largest region, as BoxState does"""
    episode_steps: int = 200
    """env steps per runtime for the in-episode timing (0: skip it)"""
    segment_sizes: list[int] = field(default_factory=lambda: [0])
    """the sides the network segments each frame at (`FCNConfig.segment_size`; 0: its training size): every
    runtime is timed at each"""


def time_calls(fn, repeats: int) -> np.ndarray:
    for _ in range(5):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return np.array(times)


def time_interleaved(calls: dict, repeats: int, block: int = 5) -> dict[str, np.ndarray]:
    """Seconds per call of each of `calls`, timed in alternating blocks of `block` calls so that each sees
    the same machine load."""
    times = {name: [] for name in calls}
    for fn in calls.values():
        for _ in range(5):
            fn()
    for _ in range(max(1, repeats // block)):
        for name, fn in calls.items():
            for _ in range(block):
                start = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - start)
    return {name: np.array(t) for name, t in times.items()}


def alternate(*calls):
    """One call that runs each of `calls` in turn."""
    cycle = itertools.cycle(calls)
    return lambda: next(cycle)()


def env_step_ms(size: int, repeats: int) -> float:
    env = gym.make(ENV_ID, **EnvConfig(start_pose="search", image_size=size).task_kwargs())
    env.reset(seed=0)
    moves = np.array([[0.0, 0.03, 0.0], [0.0, -0.03, 0.0]], dtype=np.float32)
    steps = iter(range(10**9))
    times = time_calls(lambda: env.step(moves[next(steps) % 2]), repeats)
    env.close()
    return 1000 * float(np.median(times))


def verifier_on_torch(model):
    """A copy of `model` whose verifier runs in torch whatever `predict`'s runtime."""
    variant = copy.deepcopy(model)
    verify = variant.verify
    variant.verify = lambda *args, runtime, **kwargs: verify(*args, runtime="torch", **kwargs)
    return variant


def runtime_variants(model, runtimes: list[str], torch_verifier: bool) -> dict[str, tuple]:
    """{name: (model, `predict`'s runtime)}: each of `runtimes`, and with `torch_verifier` (and a verifier)
    "onnxruntime, verifier on torch"."""
    variants = {r: (model, r) for r in runtimes}
    if torch_verifier and model.verifier is not None:
        variants["onnxruntime, verifier on torch"] = (verifier_on_torch(model), "onnxruntime")
    return variants


class TimedSegmenter:
    """`model` with `predict_with_presence` run on `runtime` and timed: what BoxState calls at every step."""

    def __init__(self, model, runtime: str):
        self.model, self.runtime, self.seconds = model, runtime, []

    def predict_with_presence(self, *args, **kwargs):
        start = time.perf_counter()
        outputs = self.model.predict_with_presence(*args, runtime=self.runtime, **kwargs)
        self.seconds.append(time.perf_counter() - start)
        return outputs


def in_episode_ms(variants: dict[str, tuple], size: int, steps: int, block: int = 5) -> dict[str, np.ndarray]:
    """Milliseconds per `predict` inside env steps (FCN box state, `size`², random directions), one env per
    variant (`runtime_variants`), stepped in alternating blocks."""
    segmenters = {name: TimedSegmenter(*variant) for name, variant in variants.items()}
    config = EnvConfig(image_size=size, box_source="fcn", start_pose="search")
    envs = {name: make_env(config, segmenter=segmenter) for name, segmenter in segmenters.items()}
    rng = np.random.default_rng(0)
    for env in envs.values():
        env.reset(seed=0)
    for segmenter in segmenters.values():
        segmenter.seconds.clear()  # the first call builds the ONNX Runtime graph
    for _ in range(max(1, steps // block)):
        for env in envs.values():
            for _ in range(block):
                *_, terminated, truncated, _ = env.step(int(rng.integers(6)))
                if terminated or truncated:
                    env.reset()
    for env in envs.values():
        env.close()
    return {name: 1000 * np.array(segmenter.seconds) for name, segmenter in segmenters.items()}


def main(args: Args):
    torch.set_num_threads(1)
    model, _ = load_checkpoint(args.weights or WEIGHTS_PATH)
    variants = {}
    for segment_size in args.segment_sizes:
        segmenting = segmenting_at(copy.deepcopy(model), segment_size)
        suffix = f", segmenting at {segment_size}²" if segment_size else ""
        for name, variant in runtime_variants(segmenting, args.runtimes, args.verifier_on_torch).items():
            variants[name + suffix] = variant
    rng = np.random.default_rng(0)
    print(
        f"FCN trained at {model.config.image_size}², {sum(p.numel() for p in model.parameters())} parameters; torch threads: {torch.get_num_threads()}; largest_component: {args.largest_component}"
    )
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    print(
        "| frame | batch | runtime | ms/frame, same target (median) | (min) | ms/frame, new target (median) | (min) | env step ms (median, reference) | FCN same target / env step |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes:
        reference = env_step_ms(size, args.repeats) if args.env_reference else float("nan")
        for batch in args.batch_sizes:
            scene = rng.integers(0, 256, (batch, size, size, 3), dtype=np.uint8)
            targets = rng.integers(
                0, 256, (2, batch, model.config.target_size, model.config.target_size, 3), dtype=np.uint8
            )
            predict = {
                name: functools.partial(m.predict, largest_component=args.largest_component, runtime=r)
                for name, (m, r) in variants.items()
            }
            same_target = {name: functools.partial(p, scene, targets[0]) for name, p in predict.items()}
            new_target = {
                name: alternate(*(functools.partial(p, scene, t) for t in targets)) for name, p in predict.items()
            }  # timed apart from same_target, whose calls would otherwise find the cache holding the other target
            times = {
                (r, case): 1000 * t / batch
                for case, calls in (("same", same_target), ("new", new_target))
                for r, t in time_interleaved(calls, args.repeats).items()
            }
            for runtime in variants:
                same, new = times[runtime, "same"], times[runtime, "new"]
                median = float(np.median(same))
                print(
                    f"| {size}² | {batch} | {runtime} | {median:.2f} | {same.min():.2f} | {np.median(new):.2f} | {new.min():.2f} | {reference:.2f} | {median / reference:.2f} |"
                )
    if args.episode_steps:
        size = args.sizes[0]
        print(
            f"\n`predict` inside env steps, {size}², batch 1, largest component (load average {os.getloadavg()[0]:.2f})"
        )
        print("\n| runtime | ms per step's predict (median) | (min) |\n|---|---|---|")
        for runtime, ms in in_episode_ms(variants, size, args.episode_steps).items():
            print(f"| {runtime} | {np.median(ms):.2f} | {ms.min():.2f} |")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main(tyro.cli(Args))
