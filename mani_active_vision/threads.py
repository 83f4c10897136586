"""Threads for worker processes: lavapipe's render threads from the number of workers and cores, torch's, and
the cores each worker runs on.

lavapipe (the software Vulkan SAPIEN renders with on the CPU) starts one render thread per core in every
process, so N workers on N cores run N² render threads that fight for the cores (measured: 2 workers on 2
cores gave 0.81-1.19x one worker with lavapipe's default, 2.5x with one render thread each; docs/speed.md).
Each worker gets its share of the cores instead: lavapipe the share less the worker's own thread, but at
least one (with none, the worker rasterises in its own thread: measured no faster, 73 against 81 steps/s
for 2 workers on 2 cores). torch (and ONNX Runtime, which sizes the FCN's session from torch) gets one
thread whatever the share: a worker's tensors are one image's, and a pool of two threads made one worker
3.4x slower (37 against 124 steps/s, interleaved, on a loaded 2-core machine). A `LP_NUM_THREADS` the user
set wins, for every worker.

Where the workers split the cores evenly, each worker's threads are also pinned to its own cores: a worker's
step is a chain (its thread hands the frame to its render thread and waits), and left to the scheduler the
other worker's threads preempt that chain, so every step waits for the slower of the two. Measured on 2 cores
(docs/speed.md, `baselines/benchmark.py`, 9 quiet runs): 2 workers 1.76-1.93x one worker pinned, 1.52-1.66x not.

    threads = worker_threads(num_workers)  # in the parent, when the workers are planned
    cores = worker_cores(num_workers)      # ... and the cores of each (None: not pinned)
    use_worker_threads(dataclasses.replace(threads, cores=cores[i]))  # first thing in worker i, before SAPIEN
                                                                      # makes its renderer
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class WorkerThreads:
    render: int
    """lavapipe's render threads (`LP_NUM_THREADS`)"""
    torch: int = 1
    """torch's intra-op threads (`torch.set_num_threads`)"""
    cores: tuple[int, ...] | None = None
    """the cores the worker's threads run on (`os.sched_setaffinity`); None: wherever the scheduler puts them"""


def available_cores() -> int:
    """Cores this process may run on (its affinity mask, which a container or `taskset` may narrow)."""
    return len(os.sched_getaffinity(0))


def worker_threads(num_workers: int, cores: int | None = None) -> WorkerThreads:
    """The threads of each of `num_workers` workers sharing `cores` (default: this process's); a
    `LP_NUM_THREADS` set in this process's environment is kept as it is."""
    share = (cores or available_cores()) // num_workers
    user = os.environ.get("LP_NUM_THREADS")
    return WorkerThreads(render=int(user) if user else max(1, share - 1))


def worker_cores(num_workers: int, cores: Sequence[int] | None = None) -> list[tuple[int, ...] | None]:
    """The cores of each of `num_workers` workers on `cores` (default: this process's affinity): an equal block
    each where the workers divide the cores, one core per worker in turn where the cores divide the workers,
    else None for all (pinning some workers more tightly than others would make every step wait for the
    crowded core). One worker is not pinned: its block would be all the cores anyway; nor is any where the
    system has no affinity calls (they are Linux's)."""
    if cores is None and not hasattr(os, "sched_getaffinity"):
        return [None] * num_workers
    cores = sorted(os.sched_getaffinity(0) if cores is None else cores)
    if num_workers < 2 or not cores:
        return [None] * num_workers
    if len(cores) % num_workers == 0:
        share = len(cores) // num_workers
        return [tuple(cores[i * share : (i + 1) * share]) for i in range(num_workers)]
    if num_workers % len(cores) == 0:
        return [(cores[i % len(cores)],) for i in range(num_workers)]
    return [None] * num_workers


def use_worker_threads(threads: WorkerThreads) -> None:
    """Set `threads` in this worker process. lavapipe reads `LP_NUM_THREADS` when SAPIEN makes its Vulkan
    device (the first env of the process), so this must run before that; threads started later inherit the
    cores of the thread that starts them, and those already running are pinned here."""
    os.environ["LP_NUM_THREADS"] = str(threads.render)
    torch.set_num_threads(threads.torch)
    pin_threads(threads.cores)


def pin_threads(cores: tuple[int, ...] | None) -> None:
    """Put every thread of this process on `cores` (None: leave them). Run again once the env exists: Mesa's
    shader-cache thread gives itself every core when it starts."""
    if cores is None:
        return
    for task in os.listdir("/proc/self/task"):
        with contextlib.suppress(ProcessLookupError):  # the thread has ended since
            os.sched_setaffinity(int(task), cores)
