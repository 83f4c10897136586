"""The Ray backend and sweeps on a local Ray (2 CPUs): the same observations as the CPU backend, autoreset,
a killed actor, clear errors, and a sweep of two tiny training runs that resumes and matches a sequential one.

Ray ships this module's functions and classes to its workers by value (registered in the fixture): the
workers cannot import a test module by name.
"""

import json
import os
import signal
import subprocess
import sys
import threading
import time

import gymnasium as gym
import numpy as np
import pytest
import ray
import torch

from mani_active_vision.agents import dqn
from mani_active_vision.envs import EnvConfig
from mani_active_vision.evaluation.training_run import train_and_evaluate
from mani_active_vision.ray_vec_env import RayVectorEnv
from mani_active_vision.sweep import Run, _run_and_collect, _write_back, pending, run_sweep
from mani_active_vision.vec_env import WorkerCrashedError, make_vec_env


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    assert not ray.is_initialized()
    ray.init(address="local", num_cpus=2, include_dashboard=False)  # a new one: never another job's Ray
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    ray.shutdown()


def _wait_for_free_cpus(cpus: float, timeout: float = 10.0) -> float:
    deadline = time.time() + timeout
    while (free := ray.available_resources().get("CPU", 0)) < cpus and time.time() < deadline:
        time.sleep(0.1)
    return free


def _assert_killed(actor, timeout: float = 10.0):
    """`ray.kill` takes effect a moment later: the actor answers until then."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            ray.get(actor.call.remote("spec", (), {}))
        except ray.exceptions.RayActorError as e:
            assert "killed by `ray.kill`" in str(e)
            return
        time.sleep(0.1)
    raise AssertionError(f"actor still alive after {timeout} s")


def test_ray_backend_reproduces_the_cpu_backend_step_for_step():
    config = EnvConfig(start_pose="search", with_ee_pos=True, image_size=32, max_episode_steps=3)
    rollouts = {}
    for backend in ("ray", "cpu"):
        env = make_vec_env(config, 2, backend=backend)
        try:
            obs, info = env.reset(seed=3)
            steps = [env.step(np.array([k % 6, (k + 2) % 6])) for k in range(4)]  # truncated at step 3
            rollouts[backend] = (obs, info, steps, env.get_attr("object_names"))
        finally:
            env.close()
        if backend == "ray":
            assert isinstance(env, RayVectorEnv) and env.single_action_space == gym.spaces.Discrete(6)
            _assert_killed(env.actors[0])  # close() freed the actors
            _assert_killed(env.actors[1])
            assert _wait_for_free_cpus(2) == 2

    (obs_r, info_r, steps_r, names_r), (obs_c, info_c, steps_c, names_c) = rollouts["ray"], rollouts["cpu"]
    assert obs_r.shape == (2, 7) and obs_r.dtype == np.float32
    np.testing.assert_array_equal(obs_r, obs_c)
    assert names_r == names_c and names_r[0] != names_r[1]  # env i got seed 3 + i on both backends
    assert info_r.keys() == info_c.keys()
    for (o_r, rew_r, term_r, trunc_r, i_r), (o_c, rew_c, term_c, trunc_c, i_c) in zip(steps_r, steps_c):
        np.testing.assert_array_equal(o_r, o_c)
        np.testing.assert_array_equal(rew_r, rew_c)
        assert rew_r.dtype == np.float64 and term_r.dtype == trunc_r.dtype == np.bool_
        np.testing.assert_array_equal(term_r, term_c)
        np.testing.assert_array_equal(trunc_r, trunc_c)
        assert i_r.keys() == i_c.keys()
        np.testing.assert_array_equal(i_r["target_bbox"], i_c["target_bbox"])
    _, _, _, truncated, info = steps_r[2]
    assert truncated.all() and info["_final_obs"].all()  # same-step autoreset: the episode's last obs
    np.testing.assert_array_equal(np.stack(info["final_obs"]), np.stack(steps_c[2][4]["final_obs"]))
    np.testing.assert_array_equal(info["elapsed_steps"], [0, 0])  # the obs returned is the new episode's


class _Slow(gym.Wrapper):
    """A step that takes `seconds` (set through the vector env's `set_attr`)."""

    seconds = 0.0

    def step(self, action):
        time.sleep(self.seconds)
        return self.env.step(action)


def test_env_errors_reach_the_caller_and_an_actor_killed_mid_step_is_named_and_the_others_released():
    env = RayVectorEnv([lambda: _Slow(gym.make("CartPole-v1"))] * 2)
    env.reset(seed=0)
    with pytest.raises(AssertionError, match="invalid"):  # CartPole's own check of the action, as itself
        env.step(np.array([0, 7]))
    with pytest.raises(ValueError, match="list of 3 seeds.*num_envs=2"):
        env.reset(seed=[0, 1, 2])
    env.set_attr("seconds", 3.0)
    assert env.get_attr("seconds") == (3.0, 3.0)
    threading.Timer(0.5, os.kill, (env.pids[1], signal.SIGKILL)).start()
    start = time.time()
    with pytest.raises(WorkerCrashedError, match=r"worker 1 \(Ray actor, pid \d+ on node .*\) died during step"):
        env.step(np.array([0, 1]))
    assert time.time() - start < 2.5  # seen when it happened, not after worker 0's 3-second step
    _assert_killed(env.actors[0])  # worker 0 was released with it
    with pytest.raises(WorkerCrashedError, match="lost an actor earlier"):
        env.step(np.array([0, 1]))
    env.close()
    with pytest.raises(gym.error.ClosedEnvironmentError):
        env.step(np.array([0, 1]))
    assert _wait_for_free_cpus(2) == 2


def test_bad_ray_arguments_are_clear_errors():
    with pytest.raises(gym.error.NameNotFound):  # an env that cannot be made: its own error, its actor freed
        make_vec_env("NoSuchEnv-v0", 1, backend="ray")
    with pytest.raises(ValueError, match="num_envs=3 Ray actors need one CPU each, and the Ray cluster has 2 CPUs"):
        make_vec_env("CartPole-v1", 3, backend="ray")
    with pytest.raises(ValueError, match="address='auto' is the Ray cluster's: it needs backend='ray'"):
        make_vec_env("CartPole-v1", 1, backend="cpu", address="auto")
    assert _wait_for_free_cpus(2) == 2


def _tiny_runs(seeds=(0, 1)):
    env = EnvConfig(image_size=32, max_episode_steps=8)
    return [
        Run(
            f"tiny/seed{seed}",
            train_and_evaluate,
            (dqn.Args(env=env, seed=seed, episodes=1, learning_starts=4, target_update_steps=4), 1, False),
        )
        for seed in seeds
    ]


def _results(run_dir):
    history = json.loads((run_dir / "history.json").read_text())
    del history["seconds"], history["config"]["run_dir"]
    weights = torch.load(run_dir / "q_network.pt", weights_only=True)["state_dict"]
    return history, json.loads((run_dir / "eval.json").read_text()), weights


def test_a_sweep_runs_as_ray_tasks_resumes_and_matches_a_sequential_one(tmp_path):
    runs = _tiny_runs()
    ran = run_sweep(runs, str(tmp_path / "ray"))
    assert sorted(ran) == ["tiny/seed0", "tiny/seed1"] and all(ran.values())
    assert run_sweep(runs, str(tmp_path / "ray")) == {}  # finished runs are skipped
    assert run_sweep(runs, str(tmp_path / "seq"), sequential=True) == {"tiny/seed0": None, "tiny/seed1": None}
    for name in ran:
        history, evaluation, weights = _results(tmp_path / "ray" / name)
        history_seq, evaluation_seq, weights_seq = _results(tmp_path / "seq" / name)
        assert history == history_seq and evaluation == evaluation_seq
        assert weights.keys() == weights_seq.keys() and all(torch.equal(weights[k], weights_seq[k]) for k in weights)
    assert _results(tmp_path / "ray" / "tiny/seed0")[0] != _results(tmp_path / "ray" / "tiny/seed1")[0]


def test_sweep_bookkeeping_failures_and_files_shipped_back(tmp_path):
    def write(run_dir, text, with_marker=True):
        os.makedirs(os.path.join(run_dir, "sub"), exist_ok=True)
        with open(os.path.join(run_dir, "sub", "data.txt"), "w") as f:
            f.write(text)
        if text == "boom":
            raise ValueError("boom")
        if with_marker:
            with open(os.path.join(run_dir, "eval.json"), "w") as f:
                f.write("{}")

    runs = [Run("a", write, ("A",)), Run("b", write, ("boom",))]
    with pytest.raises(RuntimeError, match="1 of 2 runs failed: b; rerun to retry them"):
        run_sweep(runs, str(tmp_path / "out"))
    assert [r.name for r in pending(runs, str(tmp_path / "out"))] == ["b"]  # "a" was saved all the same
    with pytest.raises(ValueError, match=r"unique.*\['a', 'a'\]"):
        pending([runs[0], runs[0]], str(tmp_path))
    with pytest.raises(RuntimeError, match="finished without writing its marker 'eval.json'"):
        _run_and_collect((str(tmp_path / "c"), Run("c", write, ("C", False))))
    # a node without the driver's file system: the files come back with the result and are written here
    files = _run_and_collect((str(tmp_path / "worker" / "a"), runs[0]))
    assert files == {"sub/data.txt": b"A", "eval.json": b"{}"}
    _write_back(str(tmp_path / "driver" / "a"), files, "eval.json")
    assert (tmp_path / "driver" / "a" / "sub" / "data.txt").read_text() == "A"
    assert (tmp_path / "driver" / "a" / "eval.json").exists() and not list((tmp_path / "driver").rglob("*.part"))


def test_without_ray_the_cpu_backend_and_sequential_sweeps_work_and_ray_says_how_to_install_it(tmp_path):
    code = """
import sys
sys.modules["ray"] = None  # as if Ray were not installed
import gymnasium as gym
import numpy as np
from mani_active_vision.vec_env import CPUVectorEnv, make_vec_env
from mani_active_vision.sweep import Run, run_sweep
env = CPUVectorEnv([lambda: gym.make("CartPole-v1")], context="forkserver")  # the CPU backend's pool
env.reset(seed=0); env.step(np.array([0])); env.close()
def write(run_dir):
    import os; os.makedirs(run_dir); open(os.path.join(run_dir, "eval.json"), "w").close()
assert run_sweep([Run("a", write)], sys.argv[1], sequential=True) == {"a": None}
for attempt in (lambda: make_vec_env("CartPole-v1", 1, backend="ray"), lambda: run_sweep([Run("b", write)], sys.argv[1])):
    try:
        attempt()
    except ModuleNotFoundError as e:
        assert "pip install -e '.[distributed]'" in str(e), e
    else:
        raise AssertionError("no error without Ray")
print("ok")
"""
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
