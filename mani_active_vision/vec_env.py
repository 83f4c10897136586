"""Batched rollouts: N copies of a task stepped together, with or without a GPU (docs/design.md §11).

`make_vec_env(config, num_envs)` returns `num_envs` copies of the project's env (`envs.make_env(config)`:
the task, `DiscreteDirections` and the config's box state) as a gymnasium `VectorEnv`;
`make_vec_env(env_id, num_envs, wrappers=(...), **env_kwargs)` does the same for any registered env:
- CPU (`backend="cpu"`, the default without CUDA): an `AsyncVectorEnv` of `num_envs` worker processes,
  each holding one `CPUGymWrapper`-wrapped env (ManiSkill's CPU backend takes `num_envs=1` only), with
  lavapipe's render threads set from `num_envs` and the cores, one torch thread, and (`pin_workers`, where
  the workers split the cores evenly) each worker's threads on its own cores (`mani_active_vision.threads`;
  an `LP_NUM_THREADS` the user set wins). Observations, rewards and infos
  are numpy arrays with a leading env dimension.
- GPU (`backend="gpu"`, the default with CUDA): one ManiSkill env with `num_envs` parallel scenes on the
  GPU physics backend, in ManiSkill's `ManiSkillVectorEnv`; observations are torch tensors on the GPU.
- Ray (`backend="ray"`, never the default; `pip install -e '.[distributed]'`): each env in a Ray actor on
  this machine or across a cluster (`address`), with the CPU backend's layout, autoreset and seeding
  (`mani_active_vision/ray_vec_env.py`, docs/distributed.md).

All reset finished episodes in the same step (gymnasium's `SAME_STEP` autoreset: the last observation of
an episode is in `info["final_obs"]`). `wrappers` (e.g. `DiscreteDirections`,
`functools.partial(BoxState, with_ee_pos=True)`) are applied to each env, innermost first; on the CPU and on Ray
they run inside the workers, so they must be picklable (classes, `functools.partial`, module-level functions).

Seeds follow gymnasium: `reset(seed=s)` seeds worker i with `s + i` (the GPU backend derives the scenes'
seeds from `s` in ManiSkill's way), so workers differ and a run reproduces. A worker that dies raises
`WorkerCrashedError` in the parent instead of hanging, and `close()` always reaps the workers.
"""

from __future__ import annotations

import dataclasses
import functools
import multiprocessing
import multiprocessing.connection
import signal
from collections.abc import Callable, Sequence

import gymnasium as gym
import torch
from gymnasium.vector import AsyncVectorEnv, AutoresetMode

from mani_active_vision.envs import ENV_ID, EnvConfig, wrap_env
from mani_active_vision.threads import WorkerThreads, pin_threads, use_worker_threads, worker_cores, worker_threads
from mani_active_vision.vec_errors import WorkerCrashedError

BACKENDS = ("auto", "cpu", "gpu", "ray")
START_METHODS = ("forkserver", "spawn")


def make_vec_env(
    env_id: str | EnvConfig,
    num_envs: int,
    wrappers: Sequence[Callable[[gym.Env], gym.Env]] = (),
    backend: str = "auto",
    start_method: str = "forkserver",
    address: str | None = None,
    pin_workers: bool = True,
    **env_kwargs,
) -> gym.vector.VectorEnv:
    """`num_envs` copies of `env_id` (made with `env_kwargs`), or of the project's env for an `EnvConfig`
    (then `wrappers` go around its box state), as one vector env; see the module docstring. `address`: the
    Ray cluster of `backend="ray"` (None: a local Ray; "auto" or "ray://host:10001": join that cluster).
    `pin_workers` (CPU backend): each worker's threads on its own cores where the workers split them evenly
    (False: leave them to the scheduler; pinned was no slower beside other busy processes, docs/speed.md)."""
    if isinstance(env_id, EnvConfig):
        if env_kwargs:
            raise ValueError(
                f"with an EnvConfig, options go in the config, not in env_kwargs: got {sorted(env_kwargs)}"
            )
        config, env_id = env_id, ENV_ID
        env_kwargs = {k: v for k, v in config.task_kwargs().items() if k != "render_backend"}
        wrappers = (functools.partial(wrap_env, config=config), *wrappers)
    if backend not in BACKENDS:
        raise ValueError(f"backend={backend!r} is not one of: {', '.join(BACKENDS)}")
    if start_method not in START_METHODS:
        raise ValueError(f"start_method={start_method!r} is not one of: {', '.join(START_METHODS)}")
    if not (isinstance(num_envs, int) and num_envs >= 1):
        raise ValueError(f"num_envs={num_envs!r} must be a positive integer")
    if "num_envs" in env_kwargs:
        raise ValueError("pass num_envs as make_vec_env's argument, not in env_kwargs")
    if address is not None and backend != "ray":
        raise ValueError(f"address={address!r} is the Ray cluster's: it needs backend='ray', not {backend!r}")
    if backend == "auto":
        backend = "gpu" if torch.cuda.is_available() else "cpu"
    if backend == "gpu":
        return _make_gpu_vec_env(env_id, num_envs, wrappers, env_kwargs)
    env_kwargs.setdefault("render_backend", "cpu")
    if backend == "ray":
        # Ray is an optional extra: its backend is imported only when asked for (an ImportError that says
        # how to install it if Ray is missing), so that the CPU and GPU backends work without it
        from mani_active_vision.ray_vec_env import RayVectorEnv

        env_fn = functools.partial(_make_worker_env, env_id, tuple(wrappers), env_kwargs)  # the actor sets threads
        return RayVectorEnv([env_fn] * num_envs, address=address)
    threads = worker_threads(num_envs)
    cores = worker_cores(num_envs) if pin_workers else [None] * num_envs
    env_fns = [
        functools.partial(_make_worker_env, env_id, tuple(wrappers), env_kwargs, dataclasses.replace(threads, cores=c))
        for c in cores
    ]
    return CPUVectorEnv(env_fns, context=start_method, autoreset_mode=AutoresetMode.SAME_STEP)


def _make_worker_env(
    env_id: str, wrappers: Sequence[Callable], env_kwargs: dict, threads: WorkerThreads | None = None
) -> gym.Env:
    """Runs in each worker: the worker's `threads` (set before its env makes the renderer), one CPU env, the
    caller's wrappers. gymnasium also calls it once in the parent, to read the spaces from a throwaway env:
    the parent's threads are left alone."""
    if threads is not None and multiprocessing.parent_process() is not None:
        use_worker_threads(threads)
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    import mani_active_vision  # noqa: F401  (registers the task in a fresh worker process)

    env = CPUGymWrapper(gym.make(env_id, num_envs=1, **env_kwargs))
    for wrap in wrappers:
        env = wrap(env)
    if threads is not None and multiprocessing.parent_process() is not None:
        pin_threads(threads.cores)  # again: threads the renderer started may have set their own cores
    return env


def _make_gpu_vec_env(env_id: str, num_envs: int, wrappers: Sequence[Callable], env_kwargs: dict):
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    import mani_active_vision  # noqa: F401

    env = gym.make(env_id, num_envs=num_envs, sim_backend="physx_cuda", **env_kwargs)
    for wrap in wrappers:
        env = wrap(env)
    return ManiSkillVectorEnv(env, ignore_terminations=False, record_metrics=True)  # resets like the CPU pool


class CPUVectorEnv(AsyncVectorEnv):
    """gymnasium's `AsyncVectorEnv`, plus: a dead worker raises `WorkerCrashedError` (gymnasium would block
    or raise a bare `EOFError`, then fail to close), and `close()` terminates what it cannot close."""

    def _dead_worker(self) -> WorkerCrashedError | None:
        """The error of a worker that died without a word. A worker that reported an exception exits by itself
        (gymnasium's worker): that is not a crash, and the exception it reported is raised as usual."""
        if not self.error_queue.empty():
            return None
        for index, (pipe, process) in enumerate(zip(self.parent_pipes, self.processes)):
            if pipe is not None and not process.is_alive():
                self._state = type(self._state).DEFAULT
                return WorkerCrashedError(
                    f"vector env worker {index} (pid {process.pid}) died: {_exit_reason(process.exitcode)}"
                )
        return None

    def _guarded(self, call, *args, **kwargs):
        """Run a send or receive of the base class; a broken pipe from a dead worker becomes its error."""
        if (error := self._dead_worker()) is not None:
            raise error
        try:
            return call(*args, **kwargs)
        except (OSError, EOFError) as e:
            # the pipe broke first; the process's exit is reported a moment later (forkserver)
            multiprocessing.connection.wait([p.sentinel for p in self.processes], timeout=5.0)
            if (error := self._dead_worker()) is not None:
                raise error from e
            raise

    def _wait_for_answers(self):
        """Block until every live worker has answered or died (gymnasium would block for good on a dead one)."""
        for pipe, process in zip(self.parent_pipes, self.processes):
            if pipe is not None and not pipe.closed:
                while not pipe.poll() and process.is_alive():
                    multiprocessing.connection.wait([pipe, process.sentinel])
                if not pipe.poll():  # died without answering
                    raise self._dead_worker()

    def _guarded_wait(self, wait, timeout):
        if timeout is None:
            self._wait_for_answers()
        return self._guarded(wait, timeout)

    def reset_async(self, *args, **kwargs):
        return self._guarded(super().reset_async, *args, **kwargs)

    def step_async(self, actions):
        return self._guarded(super().step_async, actions)

    def call_async(self, name, *args, **kwargs):
        return self._guarded(super().call_async, name, *args, **kwargs)

    def reset_wait(self, timeout=None):
        return self._guarded_wait(super().reset_wait, timeout)

    def step_wait(self, timeout=None):
        return self._guarded_wait(super().step_wait, timeout)

    def call_wait(self, timeout=None):
        return self._guarded_wait(super().call_wait, timeout)

    def close_extras(self, timeout=None, terminate=False):
        if any(not p.is_alive() for p in self.processes):
            terminate = True  # a dead worker cannot answer "close"
            self._state = type(self._state).DEFAULT
        try:
            super().close_extras(timeout=timeout, terminate=terminate)
        finally:
            for process in self.processes:
                if process.is_alive():
                    process.terminate()
                process.join()


def _exit_reason(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        return f"killed by {signal.Signals(-exitcode).name}"
    return f"exit code {exitcode}"
