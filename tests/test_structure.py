"""The env config and the one way to build an env, checkpoint round trips and command-line overrides, strict
JSON, clear errors for wrong actions, the perturbation protocol, and that training imports no Rerun."""

import dataclasses
import json
import math
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task

import mani_active_vision as mav
from mani_active_vision.agents import dqn
from mani_active_vision.agents.q_network import QNetwork, checkpoint_env_config, load_q_network, save_q_network
from mani_active_vision.box_state import BoxState
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.perturbation import PushedPolicy
from mani_active_vision.json_io import json_safe, save_json
from mani_active_vision.metrics import Trajectory


def test_env_config_validates_and_replaces_by_name():
    with pytest.raises(ValueError, match="box_source='yolo' is not one of: ground_truth, fcn, projection, none"):
        EnvConfig(box_source="yolo")
    with pytest.raises(ValueError, match="with_ee_pos appends to the box state"):
        EnvConfig(box_source="none", with_ee_pos=True)
    config = EnvConfig().replace(object_set="unseen", image_size=32)
    assert config.object_set == "unseen" and config.task_kwargs()["sensor_configs"] == {
        "hand_camera": {"width": 32, "height": 32}
    }
    with pytest.raises(TypeError, match="no option colour; options: num_objects, object_set"):
        config.replace(colour="red")
    assert EnvConfig.from_dict(dataclasses.asdict(config)) == config
    deployed = config.on_fcn_box()  # as the shipped agents are deployed, the verifier's bars the config's own
    assert (deployed.box_source, deployed.image_size, deployed.box_hold_steps) == ("fcn", 128, 20)
    assert (deployed.fcn_acquire_threshold, deployed.fcn_track_threshold) == (0.0, 0.0)
    barred = config.on_fcn_box((0.97, 0.9))
    assert (barred.fcn_acquire_threshold, barred.fcn_track_threshold) == (0.97, 0.9)
    with pytest.raises(ValueError, match="object_set='toys' is not one of: train, unseen, primitives"):
        make_env(EnvConfig(object_set="toys"))  # the task's own options are checked by the task


def test_make_env_builds_task_directions_and_box_state():
    env = make_env(EnvConfig(start_pose="search", image_size=32, with_ee_pos=True, max_episode_steps=3))
    try:
        assert isinstance(env, BoxState) and isinstance(env.env, mav.DiscreteDirections)
        obs, info = env.reset(seed=0)
        assert obs.shape == (1, 7) and env.last_observation["sensor_data"]["hand_camera"]["rgb"].shape == (1, 32, 32, 3)
        for _ in range(3):
            obs, _, terminated, truncated, info = env.step(mav.DIRECTIONS.index("left"))
        assert bool(truncated[0]) and not bool(terminated[0])  # max_episode_steps reached the task
    finally:
        env.close()
    raw = make_env(EnvConfig(box_source="none", image_size=32))
    try:
        assert isinstance(raw, mav.DiscreteDirections) and isinstance(raw.reset(seed=0)[0], dict)
    finally:
        raw.close()


def test_checkpoint_env_is_the_default_and_flags_override_it(tmp_path):
    @dataclasses.dataclass
    class Args:
        env: EnvConfig = dataclasses.field(default_factory=EnvConfig)
        checkpoint: str = ""

    trained = EnvConfig(placement="fixed", box_source="fcn", image_size=32, max_episode_steps=40)
    path = str(tmp_path / "q.pt")
    save_q_network(path, QNetwork(4), dqn.Args(env=trained))
    assert checkpoint_env_config(path) == trained
    assert load_q_network(path)[1]["env"]["placement"] == "fixed"
    args = cli_with_checkpoint_env(Args, ["--checkpoint", path, "--env.object-set", "unseen"])
    assert args.env == trained.replace(object_set="unseen")  # one field overridden, the rest as trained
    assert cli_with_checkpoint_env(Args, []).env == EnvConfig()
    torch.save(
        {"state_dict": QNetwork(4).state_dict(), "config": {"state_dim": 4, "hidden_units": 20}}, tmp_path / "old.pt"
    )
    with pytest.raises(ValueError, match="has no env config"):
        load_q_network(str(tmp_path / "old.pt"))


def test_json_files_hold_null_not_nan(tmp_path):
    data = {"a": math.nan, "b": [1.0, float("inf")], "c": np.float32(0.5), "d": np.arange(2), "e": (1, 2)}
    assert json_safe(data) == {"a": None, "b": [1.0, None], "c": 0.5, "d": [0, 1], "e": [1, 2]}
    save_json(data, str(tmp_path / "x" / "out.json"))
    text = (tmp_path / "x" / "out.json").read_text()
    assert "NaN" not in text and "Infinity" not in text and json.loads(text)["a"] is None


def test_a_direction_index_sent_to_the_raw_task_names_the_expected_shape():
    env = cached_task(start_pose="search")
    env.reset(seed=0)
    with pytest.raises(
        ValueError, match=r"shape \(\).*expected a Cartesian step of shape \(3,\) or \(1, 3\).*DiscreteDirections"
    ):
        env.step(2)
    env.step(np.zeros(3, np.float32))  # the right shape still steps
    with pytest.raises(ValueError, match="out of range"):
        mav.DiscreteDirections(env).step(6)


def _trajectory(success, visible=None):
    t = Trajectory()
    t.success, t.visible = list(success), list(visible if visible is not None else success)
    return t


def test_pushed_policy_focuses_pushes_and_recovers():
    class Always:
        def reset(self, obs, info):
            pass

        def act(self, obs, info):
            return np.array([mav.DIRECTIONS.index("forward")])

    env = gym.make("CartPole-v1")
    env.unwrapped.num_envs = 1
    pushed = PushedPolicy(
        env, Always(), push_direction=mav.DIRECTIONS.index("up"), push_steps=2, focus_limit=5, recover_limit=3
    )
    pushed.reset(None, {})
    history = [False]
    for success, expect_stop in ((False, False), (True, False)):  # focus at the second step
        history.append(success)
        assert pushed.stop(_trajectory(history)) == expect_stop
    assert pushed.phase == "push" and int(pushed.act(None, {})[0]) == mav.DIRECTIONS.index("up")
    for success, expect_stop in (
        (False, False),
        (False, False),
        (False, False),
        (True, True),
    ):  # 2 pushes, 2 to recover
        history.append(success)
        assert pushed.stop(_trajectory(history, [True] * len(history))) == expect_stop
    assert pushed.result == {"focused": True, "visible_after_push": True, "recovered": True, "steps_to_recover": 2.0}
    pushed.reset(None, {})
    assert [pushed.stop(_trajectory([False] * (k + 2))) for k in range(5)] == [False] * 4 + [True]  # never focused
    assert not pushed.result["focused"] and math.isnan(pushed.result["steps_to_recover"])


def test_training_imports_no_rerun():
    code = "import sys, mani_active_vision.agents.dqn; assert 'rerun' not in sys.modules, 'rerun imported'"
    subprocess.run([sys.executable, "-c", code], check=True)
