"""The task under gymnasium's checker and ManiSkill's wrappers; the ground-truth box state."""

import gymnasium as gym
import h5py
import numpy as np
import torch
from conftest import cached_task
from gymnasium.utils.env_checker import check_env
from mani_skill.utils.wrappers import RecordEpisode
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

import mani_active_vision as mav
from mani_active_vision.box_state import BoxState
from mani_active_vision.envs import ENV_ID, EnvConfig


def _cpu_env(**kwargs):
    return CPUGymWrapper(gym.make(ENV_ID, **{**EnvConfig(start_pose="search", image_size=32).task_kwargs(), **kwargs}))


def test_gymnasium_env_checker_passes():
    env = mav.DiscreteDirections(_cpu_env())
    # skip_close_check: it re-creates the env from its spec, which ManiSkill's TimeLimitWrapper cannot do.
    check_env(env, skip_render_check=True, skip_close_check=True)
    obs, info = env.reset(seed=0)
    assert isinstance(obs["sensor_data"]["hand_camera"]["rgb"], np.ndarray)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert isinstance(reward, float) and isinstance(terminated, bool)
    env.close()
    env.close()  # closing twice is allowed


def test_record_episode_writes_the_trajectory(tmp_path):
    env = RecordEpisode(
        cached_task(start_pose="search"), output_dir=str(tmp_path), save_video=False, save_trajectory=True
    )
    env = mav.DiscreteDirections(env)
    env.reset(seed=0)
    for a in [0, 2, 4]:
        env.step(a)
    env.env.flush_trajectory()
    files = list(tmp_path.glob("*.h5"))
    assert files
    with h5py.File(files[0]) as f:
        actions = f["traj_0"]["actions"][()]
    assert actions.shape == (3, 3) and np.abs(actions).max() <= 0.05 + 1e-6


def test_box_state_matches_the_ground_truth_box():
    env = BoxState(mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed")), with_ee_pos=True)
    obs, info = env.reset(seed=0)
    for a in [0, 0, 0, 2, 2]:
        obs, _, _, _, info = env.step(a)
        assert obs.shape == (1, 7)
        assert torch.allclose(obs[:, :4], info["target_bbox"])
        assert torch.allclose(obs[:, 4:], env.unwrapped.agent.controller.target_pos)
    assert float(obs[0, 2]) > 0  # the fixed target is in view after orbiting left
    numpy_env = BoxState(mav.DiscreteDirections(_cpu_env()))
    obs, _ = numpy_env.reset(seed=0)
    assert isinstance(obs, np.ndarray) and obs.shape == (4,) and numpy_env.observation_space.contains(obs)
    numpy_env.close()
