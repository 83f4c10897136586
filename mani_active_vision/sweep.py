"""Experiment sweeps: many independent runs (conditions × seeds), on Ray or one after another, resumable.

    runs = [Run(f"{condition}/seed{seed}", train_and_evaluate, (...)) for condition in ... for seed in ...]
    run_sweep(runs, "runs/fig5")                      # Ray tasks on a local Ray, one CPU per run
    run_sweep(runs, "runs/fig5", address="auto")      # on the cluster this machine joined (`ray start`)
    run_sweep(runs, "runs/fig5", sequential=True)     # in this process, one after another (no Ray needed)

A run writes its results into its own folder `out_dir/<name>` and is finished once its `marker` file
(written last) is there: a rerun skips finished runs, so an interrupted sweep resumes. On Ray each run is a
task in a fresh worker process on whichever node has a free CPU; it writes where it runs, and its files
also come back to this machine, so a cluster needs no shared file system. The runs and their results are
the same as one after another: each run seeds itself and nothing passes between runs.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Run:
    """One run: `fn(run_dir, *args)` writes its results into `run_dir` (= the sweep's `out_dir/name`).
    `fn` and `args` must pickle (a module-level function, dataclasses): Ray ships them to another process."""

    name: str
    """the run's folder under the sweep's out_dir, e.g. "fixed/seed0" """
    fn: Callable[..., object]
    args: tuple = field(default=())
    marker: str = "eval.json"
    """the file in run_dir that `fn` writes last: the run is finished once it exists"""


def pending(runs: Sequence[Run], out_dir: str) -> list[Run]:
    """The runs whose marker is missing under `out_dir` (in order); names must be unique."""
    names = [r.name for r in runs]
    if len(set(names)) != len(names):
        raise ValueError(
            f"run names must be unique (each is a folder): {sorted(n for n in names if names.count(n) > 1)}"
        )
    return [r for r in runs if not os.path.exists(os.path.join(out_dir, r.name, r.marker))]


def run_sweep(
    runs: Sequence[Run], out_dir: str, address: str | None = None, sequential: bool = False
) -> dict[str, str | None]:
    """Run every unfinished run of `runs` (see the module docstring); return {name: Ray node id it ran on,
    None when sequential} for the runs that ran now. `address`: the Ray cluster (None: start a local Ray
    with one CPU per core; "auto", "host:6379", "ray://host:10001": join it). On Ray every run is tried;
    the failures are raised together at the end, after the others' results are saved."""
    out_dir = os.path.abspath(out_dir)  # the same folder for every worker process, whatever its cwd
    todo = pending(runs, out_dir)
    if sequential:
        if address is not None:
            raise ValueError(f"address={address!r} is for Ray: a sequential sweep runs in this process")
        for run in todo:
            run.fn(os.path.join(out_dir, run.name), *run.args)
        return {run.name: None for run in todo}
    return _run_on_ray(todo, out_dir, address)


def _run_on_ray(todo: list[Run], out_dir: str, address: str | None) -> dict[str, str]:
    # Ray is an optional extra: imported only when a sweep runs on it (an ImportError that says how to
    # install it if it is missing), so that sequential sweeps work without it
    from mani_active_vision.ray_cluster import as_completed

    ran, failed = {}, []
    jobs = [(os.path.join(out_dir, run.name), run) for run in todo]
    for index, node, files, error in as_completed(_run_and_collect, jobs, address=address):
        run = todo[index]
        if error is not None:
            failed.append((run.name, error))
            print(f"[sweep] {run.name} failed: {type(error).__name__}")
            continue
        _write_back(os.path.join(out_dir, run.name), files, run.marker)
        ran[run.name] = node
        print(f"[sweep] {run.name} done ({len(ran)}/{len(todo)})")
    if failed:
        names = ", ".join(name for name, _ in failed)
        raise RuntimeError(f"{len(failed)} of {len(todo)} runs failed: {names}; rerun to retry them") from failed[0][1]
    return ran


def _run_and_collect(job: tuple[str, Run]) -> dict[str, bytes]:
    """In the worker: run, then return every file of the run's folder (relative path -> bytes)."""
    run_dir, run = job
    run.fn(run_dir, *run.args)
    if not os.path.exists(os.path.join(run_dir, run.marker)):
        raise RuntimeError(f"run {run.name} finished without writing its marker {run.marker!r} in {run_dir}")
    files = {}
    for root, _, names in os.walk(run_dir):
        for name in names:
            path = os.path.join(root, name)
            files[os.path.relpath(path, run_dir)] = _read(path)
    return files


def _write_back(run_dir: str, files: dict[str, bytes], marker: str) -> None:
    """Save a run's files here unless they are here already (it ran on this machine, or on a shared file
    system); the marker goes last, so an interruption never leaves a run that looks finished but is not."""
    for relative in sorted(files, key=lambda p: p == marker):
        path = os.path.join(run_dir, relative)
        if os.path.exists(path) and _read(path) == files[relative]:
            continue
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path + ".part", "wb") as f:
            f.write(files[relative])
        os.replace(path + ".part", path)


def _read(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()
