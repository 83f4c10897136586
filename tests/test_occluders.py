"""The task's `occluders` option: validation, seeding, placement, the visibility rule, the arm's refusals."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task
from mani_skill.utils.structs import Pose

import mani_active_vision as mav
from mani_active_vision.evaluation.views import candidate_positions, meets, view_stats
from mani_active_vision.objects import OBJECT_SIZE
from mani_active_vision.occluders import (
    CLEARANCE,
    PANEL_SIZE,
    _distance_to_panel,
    panel_corners,
    panel_distance,
    points_inside,
)
from mani_active_vision.robots.iiwa import SEARCH_POS
from mani_active_vision.robots.orbit_controller import camera_end, forward_position, solve_ik, step_allowed


@pytest.mark.parametrize("value", [-1, 6, 1.5])
def test_bad_occluders_is_a_clear_error(value):
    with pytest.raises(ValueError) as err:
        gym.make("ActiveVisionFind-v0", render_backend="cpu", num_objects=5, occluders=value)
    assert f"occluders={value!r}" in str(err.value) and "from 0 to num_objects=5" in str(err.value)


def test_env_config_carries_occluders():
    config = mav.EnvConfig(occluders=2)
    assert config.task_kwargs()["occluders"] == 2
    assert mav.EnvConfig.from_dict({"occluders": 1}).occluders == 1


def test_panels_are_seeded_clear_of_everything_and_leave_the_scene_as_it_was():
    env = cached_task(occluders=2)
    plain = cached_task()
    layouts = []
    for seed in (0, 1, 0):
        obs, _ = env.reset(seed=seed)
        base = env.unwrapped
        panels = base.panel_layout()[0].numpy()
        objects = np.stack([obj.pose.p[0, :2].numpy() for obj in base.objects])
        for k, panel in enumerate(panels):
            assert _distance_to_panel(objects, panel).min() >= OBJECT_SIZE[1] / 2 + CLEARANCE - 1e-4
            # in front of object k: nearer to the base, at about its azimuth
            assert np.linalg.norm(panel[:2]) < np.linalg.norm(objects[k])
            gap = math.atan2(panel[1], panel[0]) - math.atan2(objects[k, 1], objects[k, 0])
            assert abs(math.remainder(gap, 2 * math.pi)) < 0.5
        assert _distance_to_panel(panel_corners(*panels[0]), panels[1]).min() >= CLEARANCE - 1e-4
        layouts.append(panels)
        plain_obs, _ = plain.reset(seed=seed)  # the objects and the target image are those of occluders=0
        assert torch.equal(obs["extra"]["target_image"], plain_obs["extra"]["target_image"])
        for a, b in zip(base.objects, plain.unwrapped.objects):
            assert torch.allclose(a.pose.p, b.pose.p)
    np.testing.assert_array_equal(layouts[0], layouts[2])
    assert not np.allclose(layouts[0], layouts[1])


def test_the_controller_refuses_a_step_into_a_panel():
    config = cached_task().unwrapped.agent.controller.config
    here = torch.tensor([[0.55, 0.0, 0.35]])
    qpos, _ = solve_ik(here, config.pitch)
    there = here + torch.tensor([[0.0, 0.05, 0.0]])
    camera = camera_end(there, config.pitch)[0, 2]
    panel = torch.tensor([[[float(camera[0]), float(camera[1]), 0.0]]])  # the camera would end up inside it
    assert step_allowed(there, qpos, config)[1].item()
    assert not step_allowed(there, qpos, config, panel)[1].item()
    far = panel + torch.tensor([[[0.0, 0.5, 0.0]]])
    assert step_allowed(there, qpos, config, far)[1].item()


def test_the_task_gives_its_panels_to_the_controller():
    env = mav.DiscreteDirections(cached_task(occluders=1, start_pose="search"))
    env.reset(seed=2)
    env.step(2)
    assert torch.equal(env.unwrapped.agent.controller.panels, env.unwrapped.panel_layout())


def _success_view(base):
    """Joint positions of a view in success for the current scene's target (privileged search)."""
    config = base.agent.controller.config
    points = torch.as_tensor(
        candidate_positions(base.target.pose.p[0, :2].numpy(), base.step_size, config.pitch, config.min_height),
        dtype=torch.float32,
    )
    qpos, ok = solve_ik(points, config.pitch)
    qpos = qpos[ok & (qpos[:, 3] <= config.max_elbow)]
    good = meets(view_stats(base, qpos), base.success_fraction, base.success_center_tol)
    assert good.any()
    return qpos[int(np.argmax(good))]


def test_a_target_cut_by_a_panel_is_not_a_success():
    env = cached_task(occluders=1, num_objects=1)
    env.reset(seed=5)
    base = env.unwrapped
    panel = base.panels[0]
    panel.set_pose(Pose.create_from_pq(torch.tensor([[0.0, 0.0, -3.0]])))  # out of the way first
    qpos = _success_view(base)
    base.agent.robot.set_qpos(qpos[None])
    base.forget_view()
    info = base.evaluate()
    assert bool(info["success"][0]) and float(info["target_visible_fraction"][0]) == 1.0
    # Stand the panel between the camera and the target, its edge on the line of sight to the target's centre.
    camera = camera_end(forward_position(qpos[None]), base.agent.controller.config.pitch)[0, 2]
    target = base.target.pose.p[0]
    middle = camera[:2] + 0.5 * (target[:2] - camera[:2])
    yaw = math.atan2(float(middle[1]), float(middle[0]))
    sideways = torch.tensor([-math.sin(yaw), math.cos(yaw)])
    for shift, cut in ((PANEL_SIZE[1] / 2, True), (PANEL_SIZE[1] / 2 + 0.15, False)):
        centre = middle + shift * sideways
        panel.set_pose(
            Pose.create_from_pq(torch.tensor([[*centre.tolist(), 0.0]]), [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
        )
        base.forget_view()
        info = base.evaluate()
        fraction = float(info["target_visible_fraction"][0])
        if cut:
            visible = float(info["target_fraction"][0]) * base._hand_camera_images()["segmentation"][0, ..., 0].numel()
            assert 0 < fraction < base.min_visible_fraction and not bool(info["success"][0])
            assert fraction == pytest.approx(visible / float(base._unoccluded_pixels[0]))
        else:
            assert fraction == 1.0 and bool(info["success"][0])


def test_the_search_pose_sees_no_target_behind_a_panel_straight_in_front():
    env = cached_task(occluders=1, num_objects=1)
    env.reset(seed=3)
    base = env.unwrapped
    x, y = base.target.pose.p[0, :2].tolist()
    azimuth = math.atan2(y, x)
    r = float(np.hypot(x, y))
    centre = (r - panel_distance(r, base._search_camera_rz())) * np.array([math.cos(azimuth), math.sin(azimuth)])
    base.panels[0].set_pose(
        Pose.create_from_pq(torch.tensor([[*centre, 0.0]]), [math.cos(azimuth / 2), 0, 0, math.sin(azimuth / 2)])
    )
    pos = torch.tensor([[SEARCH_POS[0] * math.cos(azimuth), SEARCH_POS[0] * math.sin(azimuth), SEARCH_POS[2]]])
    qpos, _ = solve_ik(pos, base.agent.controller.config.pitch)
    base.agent.robot.set_qpos(qpos)
    base.forget_view()
    info = base.evaluate()
    assert not bool(info["target_visible"][0]) and float(info["target_visible_fraction"][0]) == 0.0
    assert int(base._target_pixels_without_panels()[0]) > 0  # in view but for the panel


def test_data_views_keep_the_camera_out_of_the_panels():
    from mani_active_vision.segmentation_data import SegmentationDataConfig, sample_camera_position

    config = SegmentationDataConfig(view_mode_probs=(1, 0, 0, 0), height_range=(0.12, 0.5))
    object_xy = np.array([[0.8, 0.0], [0.0, 0.8]])
    panels = torch.tensor([[[0.62, 0.0, 0.0]]])  # straight in front of the target, where close views go
    pitch = cached_task().unwrapped.agent.controller.config.pitch
    rng, free_rng = np.random.default_rng(0), np.random.default_rng(0)
    inside_without = 0
    for _ in range(60):
        pos, _, _ = sample_camera_position(rng, object_xy, config, panels=panels)
        assert not points_inside(camera_end(torch.tensor(pos[None], dtype=torch.float32), pitch), panels).any()
        free, _, _ = sample_camera_position(free_rng, object_xy, config)
        inside_without += bool(
            points_inside(camera_end(torch.tensor(free[None], dtype=torch.float32), pitch), panels).any()
        )
    assert inside_without > 0  # without the panels some of these views would be inside one


def test_occlusion_rings_tell_a_target_a_panel_cuts_from_one_no_panel_hides(baseline_script):
    occlusion = baseline_script("occlusion")
    env = cached_task(occluders=1, num_objects=1)
    env.reset(seed=3)  # the target 0.81 m out: at 64² the rings of 8 forward steps see 20 px of it
    base = env.unwrapped
    pixels = int(np.prod(base._hand_camera_images()["segmentation"].shape[1:3]))
    assert occlusion.ring_views(base, 0, 10, pixels) is None  # 1.40 m: above the controller's highest
    assert occlusion.ring_views(base, 8, -3, pixels) == (True, False)  # seen, but its panel cuts it
    base.panels[0].set_pose(Pose.create_from_pq(torch.tensor([[3.0, 3.0, 0.0]])))  # the panel out of the way
    assert occlusion.ring_views(base, 8, -3, pixels) == (True, True)
    radius, height = occlusion.ring_pose(2, -3, 0.05, math.radians(60))
    assert radius == pytest.approx(0.35) and height == pytest.approx(0.90 - 0.1 * math.sin(math.radians(60)) - 0.15)


def test_success_is_split_by_what_the_search_pose_sees_and_an_unclassified_scene_is_named(baseline_script):
    occlusion = baseline_script("occlusion")
    kinds = {1: "wholly_hidden", 2: "partly_hidden", 3: "in_view", 4: "out_of_view"}
    episodes = [{"seed": 1, "success": 1.0}, {"seed": 2, "success": 0.0}, {"seed": 3, "success": 1.0}]
    assert occlusion.success_by_kind(episodes, kinds) == {"hidden": (0.5, 2), "in view": (1.0, 1)}
    with pytest.raises(ValueError, match=r"seeds \[7\]"):
        occlusion.success_by_kind([{"seed": 7, "success": 1.0}], kinds)
