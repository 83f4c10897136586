"""Batched rollouts over worker processes: shapes, per-worker seeds, and what happens when a worker dies.

One pool of 2 workers at 64² serves the task tests (a pool starts in tens of seconds: every worker
compiles its shaders). Crash handling is the vector env's own code, tested on CartPole pools that start fast.
"""

import functools
import os
import signal
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import mani_active_vision as mav
from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.threads import WorkerThreads, worker_cores, worker_threads
from mani_active_vision.vec_env import CPUVectorEnv, WorkerCrashedError, make_vec_env


@pytest.fixture(scope="module")
def pool():
    env = make_vec_env(EnvConfig(start_pose="search", with_ee_pos=True), 2)  # the project's env in each worker
    yield env
    env.close()
    assert not any(p.is_alive() for p in env.processes)


def test_batched_shapes_and_step(pool):
    assert pool.num_envs == 2
    assert pool.single_action_space == gym.spaces.Discrete(6)
    assert pool.action_space == gym.spaces.MultiDiscrete([6, 6])
    obs, info = pool.reset(seed=0)
    assert obs.shape == (2, 7) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[:, 4:], [[0.30, 0.0, 0.90]] * 2, atol=1e-5)  # the search pose
    for _ in range(3):
        obs, reward, terminated, truncated, info = pool.step(
            np.array([mav.DIRECTIONS.index("up"), mav.DIRECTIONS.index("down")])
        )
    assert obs.shape == (2, 7) and reward.shape == (2,) and terminated.shape == truncated.shape == (2,)
    assert info["target_bbox"].shape == (2, 4) and info["target_fraction"].shape == (2,)
    np.testing.assert_allclose(obs[:, :4], info["target_bbox"], atol=1e-6)  # BoxState ran in the workers
    np.testing.assert_allclose(obs[:, 6], [0.90 + 0.15, 0.90 - 0.15], atol=1e-5)  # each worker took its own action
    np.testing.assert_array_equal(info["elapsed_steps"], [3, 3])


def test_workers_get_different_seeds_that_reproduce(pool):
    def rollout(seed):
        pool.reset(seed=seed)
        names = pool.get_attr("object_names")
        observations = [pool.step(np.array([0, 0]))[0] for _ in range(5)]
        return [n[0] for n in names], np.stack(observations)

    names_a, obs_a = rollout(seed=3)
    names_b, obs_b = rollout(seed=3)
    assert names_a == names_b
    np.testing.assert_array_equal(obs_a, obs_b)
    assert names_a[0] != names_a[1]  # worker 1 got seed 4, not worker 0's seed 3
    names_c, _ = rollout(seed=4)
    assert names_c[0] == names_a[1]  # gymnasium's convention: worker i gets seed + i


def test_workers_render_with_their_share_of_the_cores(pool):
    pool.reset(seed=0)
    expected = worker_threads(2).render  # on 2 cores: 1, against lavapipe's default of one per core
    for process in pool.processes:
        tasks = Path(f"/proc/{process.pid}/task")
        names = [(task / "comm").read_text() for task in tasks.iterdir()]  # lavapipe names them llvmpipe-<i>
        assert sum(name.startswith("llvmpipe") for name in names) == expected


def test_each_worker_runs_on_its_own_cores(pool):
    pool.reset(seed=0)
    planned = worker_cores(2)  # on 2 cores: (0,) and (1,); None (not pinned) on one core
    for process, cores in zip(pool.processes, planned):
        expected = set(cores) if cores is not None else os.sched_getaffinity(0)
        for task in Path(f"/proc/{process.pid}/task").iterdir():  # every thread, the render threads included
            assert os.sched_getaffinity(int(task.name)) == expected


def test_workers_are_pinned_only_where_they_split_the_cores_evenly():
    assert worker_cores(2, cores=[0, 1]) == [(0,), (1,)]
    assert worker_cores(2, cores=[3, 5]) == [(3,), (5,)]  # the process's own cores, e.g. under taskset
    assert worker_cores(2, cores=range(8)) == [(0, 1, 2, 3), (4, 5, 6, 7)]
    assert worker_cores(4, cores=[0, 1]) == [(0,), (1,), (0,), (1,)]  # two workers per core
    assert worker_cores(3, cores=[0, 1]) == [None] * 3  # one core would hold two of the three
    assert worker_cores(3, cores=range(8)) == [None] * 3
    assert worker_cores(1, cores=[0, 1]) == [None]


def test_no_pinning_without_the_affinity_calls(monkeypatch):
    monkeypatch.delattr(os, "sched_getaffinity")  # as on macOS
    assert worker_cores(2) == [None, None]


def test_a_user_set_render_thread_count_wins(monkeypatch):
    monkeypatch.setenv("LP_NUM_THREADS", "3")
    assert worker_threads(1, cores=8) == WorkerThreads(render=3, torch=1)
    monkeypatch.delenv("LP_NUM_THREADS")
    assert worker_threads(1, cores=8) == WorkerThreads(render=7, torch=1)
    assert worker_threads(2, cores=8) == WorkerThreads(render=3, torch=1)
    assert worker_threads(4, cores=2) == WorkerThreads(render=1, torch=1)


def _cartpole_pool(n=2):
    return CPUVectorEnv([functools.partial(gym.make, "CartPole-v1")] * n, context="forkserver")


def test_killed_worker_raises_and_close_reaps():
    env = _cartpole_pool()
    env.reset(seed=0)
    os.kill(env.processes[1].pid, signal.SIGKILL)
    with pytest.raises(WorkerCrashedError, match=r"worker 1 .* killed by SIGKILL"):
        env.step(np.array([0, 1]))
    env.close()
    assert not any(p.is_alive() for p in env.processes)


def test_worker_killed_during_a_step_does_not_hang():
    env = _cartpole_pool()
    env.reset(seed=0)
    env.step_async(np.array([0, 1]))
    os.kill(env.processes[0].pid, signal.SIGKILL)
    env.processes[0].join()
    try:
        env.step_wait()  # worker 1 answered; worker 0 may or may not have before it died
    except WorkerCrashedError as e:
        assert "worker 0" in str(e)
    with pytest.raises(WorkerCrashedError, match="worker 0"):
        env.step(np.array([0, 1]))
    env.close()
    assert not any(p.is_alive() for p in env.processes)


def test_error_in_a_worker_reaches_the_parent():
    env = _cartpole_pool()
    env.reset(seed=0)
    with pytest.raises(AssertionError, match="invalid"):  # CartPole's own check of the action
        env.step(np.array([0, 7]))
    env.close()
    assert not any(p.is_alive() for p in env.processes)
    # the same when the worker has reported and exited before the parent reads (a loaded machine's timing)
    env = _cartpole_pool()
    env.reset(seed=0)
    env.step_async(np.array([0, 7]))
    env.processes[1].join(timeout=30)
    assert not env.processes[1].is_alive()
    with pytest.raises(AssertionError, match="invalid"):  # not a WorkerCrashedError: it answered first
        env.step_wait()
    env.close()


def test_a_direction_index_without_discrete_directions_says_what_to_do():
    env = make_vec_env(ENV_ID, 1, **EnvConfig(image_size=32).task_kwargs())  # any env id: no DiscreteDirections
    try:
        env.reset(seed=0)
        with pytest.raises(
            ValueError, match=r"shape \(\).*expected a Cartesian step of shape \(3,\).*DiscreteDirections"
        ):
            env.step(np.array([2]))
    finally:
        env.close()


def test_bad_arguments_name_the_valid_values():
    with pytest.raises(ValueError, match="backend='tpu' is not one of: auto, cpu, gpu, ray"):
        make_vec_env("ActiveVisionFind-v0", 2, backend="tpu")
    with pytest.raises(ValueError, match="num_envs=0"):
        make_vec_env("ActiveVisionFind-v0", 0)
    with pytest.raises(ValueError, match="options go in the config"):
        make_vec_env(EnvConfig(), 2, start_pose="search")


def test_brdf_table_is_a_physical_split_sum():
    from mani_active_vision.brdf_lut import brdf_lut_array, compute_brdf_lut

    small = compute_brdf_lut(size=8, samples=256)
    assert small.shape == (8, 8, 2) and (small >= 0).all() and (small.sum(-1) <= 1.0 + 1e-3).all()
    assert small[-1, 0, 0] > 0.95 and small[-1, 0, 1] < 0.01  # head-on, smooth: all of F0, no bias
    assert small[0, 0, 1] > 0.5  # grazing, smooth: Fresnel makes the bias large
    shipped = brdf_lut_array()
    assert shipped.shape == (128, 128, 2) and shipped.dtype == np.float32 and (shipped.sum(-1) <= 1.0 + 1e-3).all()
