"""The Ray backend of `make_vec_env`: each env in a Ray actor, on this machine or across a cluster.

`make_vec_env(config, num_envs, backend="ray", address=None)` builds a `RayVectorEnv`: one actor per env
(one CPU each, anywhere in the cluster Ray schedules it), holding the same env the CPU backend's workers
hold (`CPUGymWrapper`, then the wrappers), behind the same gymnasium interface as `CPUVectorEnv`: numpy
observations and infos with a leading env dimension, same-step autoreset (`info["final_obs"]`), and
`reset(seed=s)` seeding env i with `s + i`, so a Ray run reproduces a local run's observations.
A dead actor (killed, crashed, its node lost) raises `WorkerCrashedError` naming the env index; the other
actors are released at once, since on a cluster they hold CPUs others are waiting for.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array, iterate

from mani_active_vision.ray_cluster import connect, node_id, ray
from mani_active_vision.threads import use_worker_threads, worker_threads
from mani_active_vision.vec_errors import WorkerCrashedError

CLOSE_TIMEOUT_S = 10.0
"""how long `close()` waits for the envs to close themselves before it kills their actors"""


class EnvActor:
    """One env in a Ray actor process, stepped as gymnasium's `AsyncVectorEnv` workers step theirs."""

    def make(self, env_fn: Callable[[], gym.Env]) -> dict:
        """Make the env (a method, not `__init__`: an error in making it reaches the caller as itself) and
        describe it and where it runs."""
        use_worker_threads(worker_threads(1, cores=1))  # the actor holds one CPU (mani_active_vision.threads)
        self.env = env_fn()
        return dict(
            observation_space=self.env.observation_space,
            action_space=self.env.action_space,
            metadata=self.env.metadata,
            render_mode=self.env.render_mode,
            pid=os.getpid(),
            node_id=node_id(),
            node_ip=ray.util.get_node_ip_address(),
        )

    def reset(self, seed, options):
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:  # gymnasium's same-step autoreset
            final_observation, final_info = observation, info
            observation, info = self.env.reset()
            info = {"final_info": final_info, "final_obs": final_observation, **info}
        return observation, reward, terminated, truncated, info

    def call(self, name: str, args: tuple, kwargs: dict):
        attr = self.env.get_wrapper_attr(name)
        return attr(*args, **kwargs) if callable(attr) else attr

    def set_attr(self, name: str, value) -> None:
        self.env.set_wrapper_attr(name, value)

    def close(self) -> None:
        self.env.close()


class RayVectorEnv(gym.vector.VectorEnv):
    """`len(env_fns)` envs, each made by its function inside a Ray actor; see the module docstring.
    `address`: the cluster (`None`: this process's Ray, or a new local one; `"auto"`, `"host:port"`,
    `"ray://host:10001"`: join that one)."""

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], address: str | None = None):
        self.num_envs = len(env_fns)
        connect(address, num_cpus=max(self.num_envs, os.cpu_count() or 1))
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < self.num_envs:  # the actors beyond the cluster's CPUs would wait for ever
            raise ValueError(
                f"num_envs={self.num_envs} Ray actors need one CPU each, and the Ray cluster has {cpus:g} CPUs"
            )
        actor = ray.remote(num_cpus=1, max_restarts=0)(EnvActor)
        self.actors = [actor.remote() for _ in env_fns]
        self._alive, self._where = True, ["Ray actor"] * self.num_envs
        try:
            described = self._gather([a.make.remote(fn) for a, fn in zip(self.actors, env_fns)], "start-up")
        except BaseException:
            self._release()  # an env that cannot be made (or Ctrl-C): no actor is left holding a CPU
            raise
        self.pids = [d["pid"] for d in described]
        self.node_ids = [d["node_id"] for d in described]
        """where each env runs: its actor's process id and Ray node id"""
        self._where = [f"Ray actor, pid {d['pid']} on node {d['node_ip']} {d['node_id'][:8]}" for d in described]
        first = described[0]
        self.single_observation_space = first["observation_space"]
        self.single_action_space = first["action_space"]
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {**first["metadata"], "autoreset_mode": AutoresetMode.SAME_STEP}
        self.render_mode = first["render_mode"]
        self._observations = [None] * self.num_envs

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        if seed is None or isinstance(seed, int):
            seed = [None if seed is None else seed + i for i in range(self.num_envs)]  # env i gets seed + i
        if len(seed) != self.num_envs:
            raise ValueError(f"seed is a list of {len(seed)} seeds; it needs one per env: num_envs={self.num_envs}")
        options = dict(options or {})
        mask = options.pop("reset_mask", np.ones(self.num_envs, dtype=bool))
        indices = [i for i in range(self.num_envs) if mask[i]]
        results = self._gather([self.actors[i].reset.remote(seed[i], options) for i in indices], "reset", indices)
        infos = {}
        for i, (observation, info) in zip(indices, results):
            self._observations[i] = observation
            infos = self._add_info(infos, info, i)
        return self._batch(self._observations), infos

    def step(self, actions):
        refs = [actor.step.remote(a) for actor, a in zip(self.actors, iterate(self.action_space, actions))]
        results = self._gather(refs, "step")
        infos = {}
        for i, (observation, _, _, _, info) in enumerate(results):
            self._observations[i] = observation
            infos = self._add_info(infos, info, i)
        rewards = np.array([r[1] for r in results], dtype=np.float64)
        terminations = np.array([r[2] for r in results], dtype=np.bool_)
        truncations = np.array([r[3] for r in results], dtype=np.bool_)
        return self._batch(self._observations), rewards, terminations, truncations, infos

    def call(self, name: str, *args, **kwargs) -> tuple:
        return tuple(self._gather([a.call.remote(name, args, kwargs) for a in self.actors], f"call({name!r})"))

    def get_attr(self, name: str) -> tuple:
        return self.call(name)

    def set_attr(self, name: str, values) -> None:
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(f"set_attr got {len(values)} values; it needs one per env: num_envs={self.num_envs}")
        self._gather([a.set_attr.remote(name, v) for a, v in zip(self.actors, values)], f"set_attr({name!r})")

    def close_extras(self, **kwargs) -> None:
        """Close the envs (briefly: a hung one is not waited for), then kill every actor, which frees its CPU."""
        if not self._alive or not ray.is_initialized():
            return
        ray.wait([a.close.remote() for a in self.actors], num_returns=self.num_envs, timeout=CLOSE_TIMEOUT_S)
        self._release()

    def _release(self) -> None:
        if self._alive:
            for actor in self.actors:
                ray.kill(actor, no_restart=True)
        self._alive = False

    def _batch(self, observations: list):
        return concatenate(
            self.single_observation_space,
            observations,
            create_empty_array(self.single_observation_space, self.num_envs),
        )

    def _gather(self, refs: list, doing: str, indices: Sequence[int] | None = None) -> list:
        """The answers of the actors (`indices`: which ones the refs belong to, default all), in order,
        taken as they come so that a death is seen at once, whatever the others are doing. A dead actor
        releases all actors and raises `WorkerCrashedError`; an exception raised in an env is re-raised
        here as itself (Ray's error is also an instance of the env's exception class)."""
        if self.closed:
            raise gym.error.ClosedEnvironmentError(f"{doing} on a closed RayVectorEnv")
        if not self._alive:
            raise WorkerCrashedError(
                "this Ray vector env lost an actor earlier and released the others: make a new one"
            )
        indices = range(len(refs)) if indices is None else indices
        waiting = {ref: (position, index) for position, (index, ref) in enumerate(zip(indices, refs))}
        results = [None] * len(refs)
        while waiting:
            (ref,), _ = ray.wait(list(waiting), num_returns=1)
            position, index = waiting.pop(ref)
            try:
                results[position] = ray.get(ref)
            except ray.exceptions.RayActorError as e:
                self._release()
                raise WorkerCrashedError(
                    f"vector env worker {index} ({self._where[index]}) died during {doing}: "
                    f"{_reason(e)}; the other actors were released"
                ) from e
        return results


def _reason(error: Exception) -> str:
    """Ray's explanation of an actor's death, in one line (its message has the class, ids and advice too)."""
    text = str(error)
    for marker in ("The actor is dead because ", "The actor died because "):
        if marker in text:
            return text.split(marker, 1)[1].split(". ")[0].strip()
    return text.strip().splitlines()[0]
