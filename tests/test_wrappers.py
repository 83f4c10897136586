"""The task under gymnasium's checker and ManiSkill's wrappers; the ground-truth box state."""

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch
from conftest import cached_task
from gymnasium.utils.env_checker import check_env
from mani_skill.utils.wrappers import RecordEpisode
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

import mani_active_vision as mav
from mani_active_vision.box_state import BoxState
from mani_active_vision.boxes import mask_stats
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


def test_the_mask_stats_are_what_success_is_judged_on():
    mask = torch.zeros(2, 8, 8, dtype=torch.bool)
    mask[0, 2:4, 4:8] = True  # 8 pixels, centroid (6, 3): 0.25 right of the centre, 0.125 above
    torch.testing.assert_close(mask_stats(mask), torch.tensor([[0.125, 0.25, -0.125], [0.0, 0.0, 0.0]]))
    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed"))
    env = BoxState(task, with_ee_pos=True, with_mask_stats=True)
    obs, info = env.reset(seed=0)
    seen = 0
    for a in [0, 0, 0, 2, 2, 2]:
        obs, _, _, _, info = env.step(a)
        assert obs.shape == (1, 10) and env.observation_space.shape == (1, 10)
        assert torch.allclose(obs[:, :4], info["target_bbox"])  # the box and the position stay where they were
        assert torch.allclose(obs[:, 4:7], env.unwrapped.agent.controller.target_pos)
        share, dx, dy = obs[0, 7:]
        torch.testing.assert_close(share, info["target_fraction"][0])
        if share > 0:
            seen += 1
            torch.testing.assert_close(torch.hypot(dx, dy), info["target_center_offset"][0])
    assert seen > 0
    with pytest.raises(ValueError, match="with_mask_stats appends to the box state"):
        EnvConfig(box_source="none", with_mask_stats=True)


def test_the_presence_score_sits_between_the_camera_position_and_the_mask_stats_and_is_never_held():
    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed"))
    env = BoxState(task, with_ee_pos=True, with_mask_stats=True, with_presence=True, hold_steps=5)
    obs, info = env.reset(seed=0)
    seen = unseen_held = 0
    for a in [0, 0, 0, 1, 1, 1, 1, 1, 1, 2, 2, 2]:
        obs, _, _, _, info = env.step(a)
        assert obs.shape == (1, 11) and env.observation_space.shape == (1, 11)
        assert torch.allclose(obs[:, 4:7], env.unwrapped.agent.controller.target_pos)
        in_view = bool(env.last_mask.any())
        assert obs[0, 7] == float(in_view) == float(env.last_presence[0])  # the ground truth's: 1 or 0
        if in_view:  # the mask stats follow it
            torch.testing.assert_close(obs[0, 8], info["target_fraction"][0])
        seen += in_view
        unseen_held += (not in_view) and bool(obs[0, 2] > 0)  # the box held, the presence the source's own 0
    assert seen > 0 and unseen_held > 0
    with pytest.raises(ValueError, match="with_presence appends to the box state"):
        EnvConfig(box_source="none", with_presence=True)
