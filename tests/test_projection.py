"""The render-free box state (`box_source="projection"`): it renders nothing and agrees with the rendered box."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task
from mani_skill.utils.structs import Pose

import mani_active_vision as mav
from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.agents.q_network import load_q_network
from mani_active_vision.projection import extrinsic_cv, hull_mask


def test_hull_mask_fills_the_projected_square():
    # a 2 x 2 square 10 units in front of a camera looking along +z (OpenCV axes), focal 4, centre (8, 8)
    square = np.array([[[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [1.0, 1.0, 10.0], [-1.0, 1.0, 10.0]]])
    extrinsic = np.eye(3, 4)[None]
    intrinsic = np.array([[[40.0, 0.0, 8.0], [0.0, 40.0, 8.0], [0.0, 0.0, 1.0]]])
    mask = hull_mask(square, extrinsic, intrinsic, 16)[0]
    expected = torch.zeros(16, 16, dtype=torch.bool)
    expected[4:12, 4:12] = True  # pixels whose centres lie within 4 px of the centre
    assert torch.equal(mask, expected)
    behind = square * np.array([1.0, 1.0, -1.0])
    assert not hull_mask(behind, extrinsic, intrinsic, 16).any()


def test_the_camera_pose_from_link_7_is_the_renderers():
    env = cached_task(start_pose="search")
    env.reset(seed=0)
    camera = env.unwrapped._sensors["hand_camera"]
    local = camera.config.pose
    mine = extrinsic_cv(camera.config.mount.pose.raw_pose.numpy(), Pose.create(local).raw_pose[0].numpy())
    np.testing.assert_allclose(mine, camera.get_params()["extrinsic_cv"].numpy(), atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(obs_mode="rgb+segmentation"), ["render_free=True", "obs_mode='rgb+segmentation'", "state_dict"]),
        (dict(obs_mode="state_dict", occluders=1), ["render_free=True", "occluders=1"]),
    ],
)
def test_render_free_refuses_images_and_occluders(kwargs, words):
    with pytest.raises(ValueError) as err:
        gym.make("ActiveVisionFind-v0", render_backend="cpu", render_free=True, **kwargs)
    for word in words:
        assert word in str(err.value)


def test_projected_box_state_matches_the_rendered_one_and_renders_nothing():
    config = mav.EnvConfig(start_pose="search", object_set="unseen")
    projected, rendered = mav.make_env(config.replace(box_source="projection")), mav.make_env(config)
    try:
        policy = make_policy("servo", rendered)
        obs, info = rendered.reset(seed=1_000_003)
        box, _ = projected.reset(seed=1_000_003)
        policy.reset(obs, info)
        seen = agree = 0
        for _ in range(40):
            action = policy.act(obs, info)
            obs, _, _, _, info = rendered.step(action)
            box, _, _, _, projected_info = projected.step(action)
            assert projected.unwrapped._hand_images is None  # no render
            if obs[0, 2] > 0:
                seen += 1
                assert float((box - obs).abs().max()) <= 2 / 64 + 1e-6  # a pixel or two of the box
            agree += bool(info["success"][0]) == bool(projected_info["success"][0])
        assert seen >= 10 and agree >= 36
    finally:
        projected.close()
        rendered.close()


def test_the_dqn_trains_on_the_projected_box(tmp_path):
    env = mav.EnvConfig(box_source="projection", max_episode_steps=10)
    result = dqn.train(dqn.Args(env=env, episodes=2, run_dir=str(tmp_path), learning_starts=5), progress=False)
    assert len(result["history"]) == 2 and result["transitions"] > 0
    _, config = load_q_network(result["checkpoint"])
    assert config["env"]["box_source"] == "projection"


def test_a_rendered_env_projects_too_for_measuring_the_difference():
    env = cached_task(start_pose="search", placement="fixed")
    env.reset(seed=3)
    base = env.unwrapped
    for _ in range(15):
        env.step(torch.tensor([[0.0, 0.05, 0.0]]))  # orbit left until the fixed scene's target is in view
    base.forget_view()
    rendered = base._hand_camera_images()["segmentation"][..., 0] == base.target_seg_id[:, None, None]
    projected = base.projected_target_mask()
    assert rendered.any() and float((rendered & projected).sum() / (rendered | projected).sum()) > 0.5
