"""Threads for worker processes: lavapipe's render threads from the number of workers and cores, and torch's.

lavapipe (the software Vulkan SAPIEN renders with on the CPU) starts one render thread per core in every
process, so N workers on N cores run N² render threads that fight for the cores (measured: 2 workers on 2
cores gave 0.81-1.19x one worker with lavapipe's default, 2.5x with one render thread each; docs/speed.md).
Each worker gets its share of the cores instead: lavapipe the share less the worker's own thread, but at
least one (with none, the worker rasterises in its own thread: measured no faster, 73 against 81 steps/s
for 2 workers on 2 cores). torch (and ONNX Runtime, which sizes the FCN's session from torch) gets one
thread whatever the share: a worker's tensors are one image's, and a pool of two threads made one worker
3.4x slower (37 against 124 steps/s, interleaved, on a loaded 2-core machine). A `LP_NUM_THREADS` the user
set wins, for every worker.

    threads = worker_threads(num_workers)  # in the parent, when the workers are planned
    use_worker_threads(threads)            # first thing in each worker, before SAPIEN makes its renderer
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class WorkerThreads:
    render: int
    """lavapipe's render threads (`LP_NUM_THREADS`)"""
    torch: int = 1
    """torch's intra-op threads (`torch.set_num_threads`)"""


def available_cores() -> int:
    """Cores this process may run on (its affinity mask, which a container or `taskset` may narrow)."""
    return len(os.sched_getaffinity(0))


def worker_threads(num_workers: int, cores: int | None = None) -> WorkerThreads:
    """The threads of each of `num_workers` workers sharing `cores` (default: this process's); a
    `LP_NUM_THREADS` set in this process's environment is kept as it is."""
    share = (cores or available_cores()) // num_workers
    user = os.environ.get("LP_NUM_THREADS")
    return WorkerThreads(render=int(user) if user else max(1, share - 1))


def use_worker_threads(threads: WorkerThreads) -> None:
    """Set `threads` in this worker process. lavapipe reads `LP_NUM_THREADS` when SAPIEN makes its Vulkan
    device (the first env of the process), so this must run before that."""
    os.environ["LP_NUM_THREADS"] = str(threads.render)
    torch.set_num_threads(threads.torch)
