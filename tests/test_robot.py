"""The iiwa and its orbit controller: six directions, the orientation rule, refusals, the sky start."""

import math

import numpy as np
import pytest
import torch
from conftest import cached_task

import mani_active_vision as mav
from mani_active_vision.robots.orbit_controller import camera_forward, forward_position, solve_ik

STEP_TOL = 0.002  # m: measured displacement is 0.0499 ± 0.0003 per 0.05 m step


def _tilt_deg(env) -> float:
    """Angle between link 7's viewing axis and the orbit rule's, plus the horizon's roll, in degrees."""
    base = env.unwrapped
    pose = base.agent.ee_pose
    rot = pose.to_transformation_matrix()[0, :3, :3]
    azimuth = torch.atan2(pose.p[0, 1], pose.p[0, 0])
    expected = camera_forward(azimuth[None], base.agent.controller.config.pitch)[0]
    view_error = math.degrees(math.acos(float(torch.clamp(rot[:, 2] @ expected, -1, 1))))
    roll = math.degrees(math.asin(abs(float(rot[2, 1]))))  # link 7's y axis must stay horizontal
    return max(view_error, roll)


def test_ik_and_forward_kinematics_agree():
    pos = torch.tensor([[0.3, 0.0, 0.9], [0.6, 0.4, 0.3], [-0.5, 0.2, 0.5]], dtype=torch.float64)
    qpos, ok = solve_ik(pos, math.radians(60))
    assert ok.all()
    assert torch.allclose(forward_position(qpos), pos, atol=1e-9)


@pytest.mark.parametrize("direction", range(6))
def test_each_direction_moves_one_step_its_way_and_keeps_the_rule(direction):
    env = mav.DiscreteDirections(cached_task(start_pose="search"))
    env.reset(seed=0)
    base = env.unwrapped
    step = base.step_size
    for _ in range(3):
        before = base.agent.ee_pose.p[0].clone()
        _, _, _, _, info = env.step(direction)
        after = base.agent.ee_pose.p[0]
        moved = after - before
        assert not bool(info["refused"][0])
        assert abs(float(torch.linalg.norm(moved)) - step) < STEP_TOL
        azimuth = math.atan2(float(before[1]), float(before[0]))
        name = mav.DIRECTIONS[direction]
        if name in ("left", "right"):
            radius = lambda p: float(torch.linalg.norm(p[:2]))
            assert abs(radius(after) - radius(before)) < STEP_TOL and abs(float(moved[2])) < STEP_TOL
            turn = math.atan2(float(after[1]), float(after[0])) - azimuth
            assert turn > 0 if name == "left" else turn < 0
        else:
            expected = {
                "forward": camera_forward(torch.tensor([azimuth]), math.radians(60))[0],
                "up": torch.tensor([0.0, 0.0, 1.0]),
            }
            unit = expected.get(name.replace("backward", "forward").replace("down", "up"))
            sign = -1 if name in ("backward", "down") else 1
            assert float(moved @ (sign * unit.float())) / step > 0.98
        assert _tilt_deg(env) < 0.3


def test_refused_steps_hold_the_camera_untilted():
    env = mav.DiscreteDirections(cached_task(start_pose="search"))
    env.reset(seed=0)
    base = env.unwrapped
    refused = 0
    for _ in range(12):  # up from 0.90 m: the workspace ends at 1.05 m
        before = base.agent.ee_pose.p[0].clone()
        _, _, _, _, info = env.step(4)
        if bool(info["refused"][0]):
            refused += 1
            assert float(torch.linalg.norm(base.agent.ee_pose.p[0] - before)) < STEP_TOL
        assert _tilt_deg(env) < 0.3
    for _ in range(30):  # orbit right into joint 1's limit (±170°)
        _, _, _, _, info = env.step(1)
        refused += int(info["refused"][0])
        assert _tilt_deg(env) < 0.3
    assert refused >= 10
    assert int(info["refused_count"][0]) == refused
    assert abs(math.degrees(math.atan2(*base.agent.ee_pose.p[0, [1, 0]].tolist()))) < 171


def test_sky_start_points_up_then_settles_into_the_rule():
    env = mav.DiscreteDirections(cached_task(start_pose="sky"))
    env.reset(seed=0)
    base = env.unwrapped
    assert torch.allclose(base.agent.robot.get_qpos(), torch.zeros(1, 7), atol=1e-4)
    rot = base.agent.ee_pose.to_transformation_matrix()[0, :3, :3]
    assert float(rot[2, 2]) > 0.99  # looking straight up
    for _ in range(10):
        env.step(5)
    error = float(torch.linalg.norm(base.agent.ee_pose.p[0] - base.agent.controller.target_pos[0]))
    assert error < 0.005 and _tilt_deg(env) < 0.5


def test_batched_discrete_actions_are_validated():
    env = mav.DiscreteDirections(cached_task(start_pose="search"))
    env.reset(seed=0)
    for bad, error in [(6, ValueError), (-1, ValueError), (1.5, TypeError), (np.array([1, 2]), ValueError)]:
        with pytest.raises(error) as err:
            env.step(bad)
        assert "DIRECTIONS" in str(err.value) or "shape" in str(err.value) or "range" in str(err.value)
    env.step(np.int64(2))
    env.step(torch.tensor(3))
