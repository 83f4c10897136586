"""What Ray costs and gains on this machine, measured in one run (docs/distributed.md), with ratios:

1. rollouts: 2 Ray actors against 2 CPU-backend workers, the project's env at 64², random directions;
   also both with the same lavapipe threads (`LP_NUM_THREADS`: each Ray actor sets 1 unless it is set);
2. what each backend itself costs a step (2 CartPoles, whose step is microseconds);
3. a sweep of 4 short DQN runs (train, then evaluate): on a local Ray (one run per core) against one after
   another, and whether both give the same results;
4. a killed actor: how long until the error, and whether the other actor was released;
5. a two-node cluster simulated here (one CPU per node): where the runs of a sweep and the actors land.

Each measurement runs in a fresh process (its own Ray, its own forkserver); the load average is printed
with every figure, since other jobs may share the machine.

    .venv/bin/python baselines/benchmark_ray.py      # ~10 min on a loaded 2-core machine
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tyro

from mani_active_vision.agents import dqn
from mani_active_vision.envs import EnvConfig
from mani_active_vision.evaluation.training_run import train_and_evaluate
from mani_active_vision.json_io import save_json
from mani_active_vision.sweep import Run, run_sweep

ROLLOUTS = ("rollouts_cpu", "rollouts_ray", "rollouts_cpu_lp1", "rollouts_ray_lp2")
"""2-env pools: CPU workers as they are (lavapipe: a render thread per core); Ray actors (each sets
LP_NUM_THREADS=1 unless it is set); the CPU workers with one render thread; the Ray actors with two (as
the CPU workers by default, on 2 cores)"""


@dataclass
class Args:
    steps: int = 300
    """timed steps of each 2-env pool (after 20 to warm up)"""
    rounds: int = 2
    """rollout measurements per backend, interleaved (the load drifts)"""
    runs: int = 4
    """training runs of the sweep"""
    episodes: int = 5
    """training episodes per run (100 steps each)"""
    eval_episodes: int = 5
    """evaluation episodes per run"""
    out: Path = field(default_factory=lambda: Path("outputs/benchmark_ray"))
    """folder for benchmark_ray.json and the sweeps' runs"""
    only: str = ""
    """internal: run one measurement in this process and print its JSON"""
    parts: tuple[str, ...] = ("rollouts", "overhead", "sweep", "killed_actor", "cluster")
    """which measurements to run"""


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def rollouts(backend: str, steps: int) -> dict:
    from mani_active_vision.vec_env import make_vec_env

    start = time.perf_counter()
    env = make_vec_env(EnvConfig(start_pose="search"), 2, backend=backend)
    ready = time.perf_counter() - start
    rng = np.random.default_rng(0)
    try:
        env.reset(seed=0)
        for _ in range(20):
            env.step(rng.integers(6, size=2))
        start = time.perf_counter()
        for _ in range(steps):
            env.step(rng.integers(6, size=2))
        seconds = time.perf_counter() - start
    finally:
        env.close()
    return {"steps_per_s": 2 * steps / seconds, "ready_s": ready, "load": load()}


def overhead(steps: int) -> dict:
    """Milliseconds per step of 2 CartPoles (microseconds of work): what each backend itself costs a step."""
    import gymnasium as gym

    from mani_active_vision.ray_vec_env import RayVectorEnv
    from mani_active_vision.vec_env import CPUVectorEnv

    result = {}
    for name, make in (
        ("cpu", lambda fns: CPUVectorEnv(fns, context="forkserver")),
        ("ray", lambda fns: RayVectorEnv(fns)),
    ):
        env = make([lambda: gym.make("CartPole-v1")] * 2)
        try:
            env.reset(seed=0)
            for _ in range(20):
                env.step(np.array([0, 1]))
            start = time.perf_counter()
            for _ in range(steps):
                env.step(np.array([0, 1]))
            result[f"{name}_ms_per_step"] = (time.perf_counter() - start) / steps * 1e3
        finally:
            env.close()
    return {**result, "load": load()}


def sweep_runs(args: Args, episodes: int | None = None, eval_episodes: int | None = None) -> list[Run]:
    return [
        Run(
            f"short/seed{seed}",
            train_and_evaluate,
            (
                dqn.Args(env=EnvConfig(), seed=seed, episodes=episodes or args.episodes),
                eval_episodes or args.eval_episodes,
                False,
            ),
        )
        for seed in range(args.runs)
    ]


def sweep(args: Args, mode: str) -> dict:
    out_dir = str(args.out / f"sweep_{mode}")
    start = time.perf_counter()
    if mode == "ray":
        from mani_active_vision.ray_cluster import connect

        connect()  # timed apart: what starting Ray costs
    ray_start = time.perf_counter() - start
    ran = run_sweep(sweep_runs(args), out_dir, sequential=mode == "sequential")
    return {"seconds": time.perf_counter() - start, "ray_start_s": ray_start, "ran": len(ran), "load": load()}


def killed_actor() -> dict:
    import ray

    from mani_active_vision.vec_env import WorkerCrashedError, make_vec_env

    env = make_vec_env(EnvConfig(start_pose="search"), 2, backend="ray")
    env.reset(seed=0)
    killed_at = []
    timer = threading.Timer(1.0, lambda: (killed_at.append(time.perf_counter()), os.kill(env.pids[1], signal.SIGKILL)))
    timer.start()
    try:
        while True:
            env.step(np.array([0, 1]))
    except WorkerCrashedError as e:
        reported = time.perf_counter() - killed_at[0]
        message = str(e)
    deadline, released = time.time() + 10, False
    while not released and time.time() < deadline:
        try:
            ray.get(env.actors[0].call.remote("spec", (), {}))
            time.sleep(0.05)
        except ray.exceptions.RayActorError:
            released = True
    return {"reported_after_s": reported, "message": message, "other_released": released, "load": load()}


def cluster(args: Args) -> dict:
    import gymnasium as gym
    import ray
    from ray.cluster_utils import Cluster

    from mani_active_vision.ray_vec_env import RayVectorEnv

    two = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    worker = two.add_node(num_cpus=1)
    two.wait_for_nodes()
    names = {two.head_node.node_id: "head", worker.node_id: "worker"}
    try:
        start = time.perf_counter()
        ran = run_sweep(
            sweep_runs(args, episodes=1, eval_episodes=1), str(args.out / "sweep_cluster"), address=two.address
        )
        seconds = time.perf_counter() - start
        env = RayVectorEnv([lambda: gym.make("CartPole-v1")] * 2, address=two.address)
        actors = [names[n] for n in env.node_ids]
        env.close()
    finally:
        ray.shutdown()
        two.shutdown()
    return {"runs_on": {k: names[v] for k, v in ran.items()}, "sweep_s": seconds, "actors_on": actors, "load": load()}


def same_results(a: Path, b: Path) -> bool:
    """The runs' histories (less their wall times and folders) and evaluations are equal."""
    for history in sorted(a.rglob("history.json")):
        relative = history.relative_to(a)
        left, right = (json.loads((root / relative).read_text()) for root in (a, b))
        for h in (left, right):
            del h["seconds"], h["config"]["run_dir"]
        if (
            left != right
            or (a / relative.parent / "eval.json").read_text() != (b / relative.parent / "eval.json").read_text()
        ):
            return False
    return True


def measure(args: Args, what: str) -> dict:
    """Run one measurement in a fresh process; its JSON comes back on the last line of its output."""
    command = [sys.executable, __file__, "--only", what, "--steps", str(args.steps), "--runs", str(args.runs)]
    command += ["--episodes", str(args.episodes), "--eval-episodes", str(args.eval_episodes), "--out", str(args.out)]
    env = dict(os.environ)
    if "_lp" in what:  # lavapipe's render threads per process, for this measurement's processes
        env["LP_NUM_THREADS"] = what.rsplit("_lp", 1)[1]
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{what} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    print(
        f"{what}: {result}    (uptime: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()})",
        flush=True,
    )
    return result


def main(args: Args):
    if args.only:
        if args.only.startswith("rollouts_"):
            result = rollouts(args.only.split("_")[1], args.steps)
        elif args.only in ("sweep_sequential", "sweep_ray"):
            result = sweep(args, args.only.removeprefix("sweep_"))
        elif args.only == "overhead":
            result = overhead(args.steps)
        elif args.only == "killed_actor":
            result = killed_actor()
        elif args.only == "cluster":
            result = cluster(args)
        else:
            raise ValueError(f"only={args.only!r} is not a measurement of this script")
        print(json.dumps(result))
        return
    for stale in ("sweep_sequential", "sweep_ray", "sweep_cluster"):  # a benchmark times fresh runs
        shutil.rmtree(args.out / stale, ignore_errors=True)
    print(f"uptime at start: {uptime()}", flush=True)
    results, lines = {}, []
    if "rollouts" in args.parts:
        r = results["rollouts"] = {k: [] for k in ROLLOUTS}
        for _ in range(args.rounds):
            for what in ROLLOUTS:
                r[what].append(measure(args, what))
        mean = {k.removeprefix("rollouts_"): float(np.mean([m["steps_per_s"] for m in v])) for k, v in r.items()}
        ratios = results["rollout_ratios"] = {  # per round: measured a minute apart, under about the same load
            f"{a}/{b}": [x["steps_per_s"] / y["steps_per_s"] for x, y in zip(r[f"rollouts_{a}"], r[f"rollouts_{b}"])]
            for a, b in (("ray", "cpu"), ("ray_lp2", "cpu"), ("ray", "cpu_lp1"))
        }
        lines.append(f"rollouts, 2 envs at 64², steps/s, mean of {args.rounds} rounds:")
        lines.append("  " + ", ".join(f"{k} {v:.1f}" for k, v in mean.items()))
        lines += [
            f"  {k} per round: {', '.join(f'{x:.2f}' for x in v)} (target ray/cpu >= 0.9)" for k, v in ratios.items()
        ]
    if "overhead" in args.parts:
        o = results["overhead"] = measure(args, "overhead")
        lines.append(
            f"per-step cost of the backend itself (2 CartPoles): CPU workers {o['cpu_ms_per_step']:.2f} ms, "
            f"Ray actors {o['ray_ms_per_step']:.2f} ms"
        )
    if "sweep" in args.parts:
        seq = results["sweep_sequential"] = measure(args, "sweep_sequential")
        par = results["sweep_ray"] = measure(args, "sweep_ray")
        same = results["sweep_same_results"] = same_results(args.out / "sweep_sequential", args.out / "sweep_ray")
        ratio, ratio_started = par["seconds"] / seq["seconds"], (par["seconds"] - par["ray_start_s"]) / seq["seconds"]
        results["sweep_ratios"] = {"ray/sequential": ratio, "ray/sequential, Ray already started": ratio_started}
        lines.append(
            f"sweep of {args.runs} runs ({args.episodes} training, {args.eval_episodes} evaluation episodes each): "
            f"sequential {seq['seconds']:.0f} s, Ray {par['seconds']:.0f} s of which starting Ray {par['ray_start_s']:.0f} s"
        )
        lines.append(
            f"  ray/sequential {ratio:.2f} (target <= 0.6), {ratio_started:.2f} once Ray runs; same results: {same}"
        )
    if "killed_actor" in args.parts:
        k = results["killed_actor"] = measure(args, "killed_actor")
        lines.append(
            f"killed actor reported after {k['reported_after_s']:.3f} s; the other released: {k['other_released']}"
        )
        lines.append(f"  {k['message']}")
    if "cluster" in args.parts:
        c = results["cluster"] = measure(args, "cluster")
        lines.append(f"simulated 2-node cluster: sweep runs on {c['runs_on']}; actors on {c['actors_on']}")
    results["summary"] = lines
    save_json(results, str(args.out / "benchmark_ray.json"))
    print("\n" + "\n".join(lines) + f"\nuptime at the end: {uptime()}")
    print(f"wrote {args.out / 'benchmark_ray.json'}")


if __name__ == "__main__":
    main(tyro.cli(Args))
