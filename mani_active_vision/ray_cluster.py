"""Ray, the optional extra behind `make_vec_env(..., backend="ray")` and `sweep.run_sweep` (docs/distributed.md).

`connect(address)` joins a cluster or starts a local Ray; `as_completed(fn, items)` runs `fn(item)` as Ray
tasks (one CPU each) and yields each result where it ran, as it finishes.
Importing this module needs Ray (`pip install -e '.[distributed]'`); nothing else in the project does.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence

from mani_active_vision.threads import use_worker_threads, worker_threads

try:
    import ray
except ModuleNotFoundError as e:
    if e.name != "ray":
        raise
    raise ModuleNotFoundError(
        "Ray is not installed: it is an optional extra of mani-active-vision. Install it with "
        "`pip install -e '.[distributed]'` (scripts/setup.sh does), or use a backend without Ray.",
        name="ray",
    ) from e


def connect(address: str | None = None, num_cpus: int | None = None) -> None:
    """Make sure this process talks to a Ray cluster; if it already does (`ray.init` was called), nothing.

    `address=None`: start a new local Ray on this machine with `num_cpus` CPUs (default: the machine's),
    never joining another one by surprise. `"auto"` joins the cluster started on this machine with
    `ray start`; `"host:6379"` or `"ray://host:10001"` a remote one (its own CPUs count, not `num_cpus`).
    """
    if ray.is_initialized():
        return
    if address is None:
        # no dashboard: nothing here reads it, and on a small machine each of Ray's daemons slows the start
        ray.init(address="local", num_cpus=num_cpus or os.cpu_count(), include_dashboard=False)
    else:
        ray.init(address=address)


def node_id() -> str:
    """The Ray node this code runs on (in a task or actor)."""
    return ray.get_runtime_context().get_node_id()


def as_completed(
    fn: Callable, items: Sequence, address: str | None = None
) -> Iterator[tuple[int, str | None, object, BaseException | None]]:
    """Run `fn(item)` for every item as a Ray task (one CPU each) and yield `(index, node_id, result, error)`
    as each finishes: `error` is the exception a failed run raised (then `result` and `node_id` are None).
    The tasks are queued at once; Ray starts as many as the cluster has CPUs. A worker process runs one
    task after another, as a sequential loop runs its runs in one process (the imports are paid once)."""
    connect(address)
    task = ray.remote(num_cpus=1)(_on_node)
    pending = {task.remote(fn, item): index for index, item in enumerate(items)}
    try:
        while pending:
            (done,), _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(done)
            try:
                node, result = ray.get(done)
            except ray.exceptions.RayError as e:
                yield index, None, None, e
            else:
                yield index, node, result, None
    finally:
        for ref in pending:  # the caller stopped (an error, Ctrl-C): runs not yet finished are cancelled
            ray.cancel(ref, force=True)


def _on_node(fn: Callable, item):
    use_worker_threads(worker_threads(1, cores=1))  # a task holds one CPU (mani_active_vision.threads)
    return node_id(), fn(item)
