"""Holding a view: the optional `stay` action through env, policies and the DQN; the view planner's model of a
step agrees with the env's."""

import types

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task

import mani_active_vision as mav
from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import (
    STAY_INDEX,
    ServoPolicy,
    in_success_with_margin,
    make_policy,
    margin_limits,
)
from mani_active_vision.agents.q_network import load_q_network
from mani_active_vision.box_state import BoxState
from mani_active_vision.directions import STAY, action_names, direction_deltas
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.protocol import evaluate
from mani_active_vision.evaluation.views import REVERSE, neighbours
from mani_active_vision.recording.log import action_name


def test_stay_is_an_optional_seventh_action_that_holds_the_arm():
    assert action_names() == mav.DIRECTIONS and action_names(stay_action=True) == (*mav.DIRECTIONS, STAY)
    env = mav.DiscreteDirections(cached_task(start_pose="search"), stay_action=True)
    assert env.action_space.n == 7 and mav.DiscreteDirections(cached_task(start_pose="search")).action_space.n == 6
    env.reset(seed=0)
    controller = env.unwrapped.agent.controller
    env.step(mav.DIRECTIONS.index("forward"))  # the six keep their indices
    before_target, before_ee = controller.target_pos.clone(), env.unwrapped.agent.ee_pose.p.clone()
    for _ in range(3):
        _, _, _, _, info = env.step(env.names.index(STAY))
        assert not bool(info["refused"][0])
    assert torch.equal(controller.target_pos, before_target)
    assert float(torch.linalg.norm(env.unwrapped.agent.ee_pose.p - before_ee)) < 2e-3  # settled, not moving
    with pytest.raises(ValueError, match=r"valid are 0..6 = \(.*'stay'\)"):
        env.step(7)
    assert action_name(np.array([6])) == "stay" and action_name(np.array([0])) == "left"


def test_make_env_and_policies_follow_the_action_count(tmp_path):
    made = make_env(EnvConfig(stay_action=True, box_source="none", image_size=32))
    assert made.action_space.n == 7 and made.names[6] == STAY
    made.close()
    env = BoxState(mav.DiscreteDirections(cached_task(placement="random"), stay_action=True))
    random_policy = make_policy("random", env, seed=0)
    actions = {int(random_policy.act(None, {})[0]) for _ in range(200)}
    assert actions == set(range(7))  # stay included
    q_network = dqn.QNetwork(4 + 7, num_actions=7)
    with torch.no_grad():
        q_network.network[2].bias[:] = torch.tensor([0.0, 0, 0, 0, 0, 0, 1])  # prefers stay
        q_network.network[2].weight.zero_()
    policy = make_policy("dqn", env, q_network=q_network, with_last_action=True)
    obs, info = env.reset(seed=1)
    policy.reset(obs, info)
    assert int(policy.act(obs, info)[0]) == 6 and policy.state(obs)[0, 4:].tolist() == [0, 0, 0, 0, 0, 0, 1]
    six = BoxState(mav.DiscreteDirections(cached_task(placement="random")))
    with pytest.raises(ValueError, match="the Q-network has 7 actions, the env takes 6.*stay_action"):
        make_policy("dqn", six, q_network=q_network, with_last_action=True)


def test_a_short_training_run_with_stay_stores_seven_actions(tmp_path):
    env = EnvConfig(max_episode_steps=30, stay_action=True)
    args = dqn.Args(**dqn.SHAPED, env=env, episodes=1, learning_starts=10, run_dir=str(tmp_path))
    result = dqn.train(args, progress=False)
    q_network, config = load_q_network(result["checkpoint"])
    assert q_network.num_actions == 7 and config["state_dim"] == 4 + 7 and config["env"]["stay_action"]
    assert [action_names(True)[a] for a in dqn.mirrored_actions(7)] == [
        *("right", "left", "forward", "backward", "up", "down", STAY)
    ]
    last_stay = np.array([0.1, 0.2, 0.3, 0.4, 0, 0, 0, 0, 0, 0, 1])
    np.testing.assert_allclose(dqn.mirror_state(last_stay), [0.6, 0.2, 0.3, 0.4, 0, 0, 0, 0, 0, 0, 1])
    last_left = np.array([0.1, 0.2, 0.3, 0.4, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(dqn.mirror_state(last_left), [0.6, 0.2, 0.3, 0.4, 0, 1, 0, 0, 0, 0, 0])
    with_stats = np.array([0.1, 0.2, 0.3, 0.4, 0.06, -0.2, 0.05, 1, 0, 0, 0, 0, 0, 0])  # share, dx, dy; then LEFT
    np.testing.assert_allclose(
        dqn.mirror_state(with_stats, mask_stats=True), [0.6, 0.2, 0.3, 0.4, 0.06, 0.2, 0.05, 0, 1, 0, 0, 0, 0, 0]
    )
    with_position = np.concatenate([with_stats[:4], [0.5, -0.3, 0.4], with_stats[4:]])  # the camera's, after the box
    np.testing.assert_allclose(
        dqn.mirror_state(with_position, mask_stats=True, ee_pos=True),
        [0.6, 0.2, 0.3, 0.4, 0.5, -0.3, 0.4, 0.06, 0.2, 0.05, 0, 1, 0, 0, 0, 0, 0],
    )
    with_presence = np.concatenate([with_position[:7], [0.9], with_position[7:]])  # BoxState's: then the stats
    np.testing.assert_allclose(
        dqn.mirror_state(with_presence, mask_stats=True, ee_pos=True, presence=True),
        [0.6, 0.2, 0.3, 0.4, 0.5, -0.3, 0.4, 0.9, 0.06, 0.2, 0.05, 0, 1, 0, 0, 0, 0, 0],
    )


def test_the_planners_steps_are_the_envs_steps_and_reverse_exactly():
    env = mav.DiscreteDirections(cached_task(start_pose="search"))
    env.reset(seed=0)
    base = env.unwrapped
    controller = base.agent.controller
    for _ in range(8):
        env.step(mav.DIRECTIONS.index("forward"))
    for _ in range(10):  # down to the floor: "down" gets refused there, which the planner must predict
        pos, qpos = controller.target_pos.clone(), controller._target_qpos.clone()
        next_pos, _, allowed = neighbours(pos, qpos, base.step_size, controller.config)
        for d, name in enumerate(mav.DIRECTIONS):
            state = base.get_state_dict()
            controller_state = controller.get_state()
            _, _, _, _, info = env.step(d)
            assert bool(allowed[0, d]) == (not bool(info["refused"][0])), name
            expected = next_pos[0, d] if allowed[0, d] else pos[0]
            assert torch.allclose(controller.target_pos[0], expected, atol=1e-6), name
            base.set_state_dict(state)
            controller.set_state(controller_state)
        env.step(mav.DIRECTIONS.index("down"))
    assert not bool(allowed[0, mav.DIRECTIONS.index("down")])  # the floor was reached
    for name, back in REVERSE.items():
        there = pos + direction_deltas(pos, base.step_size, controller.config.pitch, (name,))[:, 0]
        again = there + direction_deltas(there, base.step_size, controller.config.pitch, (back,))[:, 0]
        assert torch.allclose(again, pos, atol=1e-6), name
    with pytest.raises(ValueError, match="unknown action names.*valid are"):
        direction_deltas(pos, 0.05, 1.0, ("sideways",))


def test_the_moves_asked_for_alone_are_those_of_all_moves_bit_for_bit():
    names = action_names(stay_action=True, fine_actions=True)
    pos = torch.tensor([[0.5, 0.1, 0.6], [-0.2, 0.6, 0.3], [0.3, -0.4, 0.9]])
    every = direction_deltas(pos, 0.1, 1.0, names, fine_step=0.025)
    for k, name in enumerate(names):  # what an env's step computes: only the move taken
        assert torch.equal(direction_deltas(pos, 0.1, 1.0, (name,), fine_step=0.025)[:, 0], every[:, k]), name
    assert torch.equal(every[:, names.index(STAY)], torch.zeros(3, 3))
    with pytest.raises(ValueError, match="need fine_step > 0"):
        direction_deltas(pos, 0.1, 1.0, ("left_fine",))


def test_learner_reward_pays_the_bonus_once_then_time_in_success():
    args = dqn.Args(success_bonus=1.0, hold_reward=0.2, step_cost=0.02, refusal_penalty=0.1)
    reward = dqn.LearnerReward(args, success_fraction=0.05)

    def info(success, refused=False):
        return {
            "success": torch.tensor([success]),
            "refused": torch.tensor([refused]),
            "target_fraction": torch.zeros(1),
            "target_center_offset": torch.tensor([float("inf")]),
        }

    reward.reset(info(False))
    env_reward = torch.zeros(1)
    steps = [(False, False), (True, False), (True, False), (False, True), (True, False)]
    paid = [reward(env_reward, info(*s)) for s in steps]
    # the first success earns the bonus; later steps in success (also after losing it) earn hold_reward
    assert paid == pytest.approx([-0.02, 0.98, 0.18, -0.12, 0.18])
    reward.reset(info(False))
    assert reward(env_reward, info(True)) == pytest.approx(0.98)  # a new episode: the bonus again
    shaped = dqn.LearnerReward(dqn.Args(**dqn.SHAPED), success_fraction=0.05)
    shaped.reset(info(False))
    assert [shaped(env_reward, info(True)) for _ in range(2)][1] == pytest.approx(-0.02)  # shaped: no hold reward
    assert dqn.PRESETS["hold"][1].hold_reward == 0.2 and not dqn.PRESETS["hold"][1].end_at_success
    still = dqn.LearnerReward(dqn.Args(step_cost=0.02, stay_penalty=0.1), success_fraction=0.05)
    still.reset(info(False))
    paid = [still(env_reward, info(s), stayed=stayed) for s, stayed in [(False, True), (True, True), (False, False)]]
    assert paid == pytest.approx([-0.12, -0.02, -0.02])  # a stay costs only out of success
    with pytest.raises(ValueError, match="hold_reward=0.2 pays for time in success.*--no-end-at-success"):
        dqn.train(dqn.Args(**{**dqn.HOLD, "end_at_success": True}), progress=False)


def test_hold_margin_pays_and_lets_stay_only_well_inside_success():
    limits = margin_limits(0.05, 0.15, 0.2)
    assert limits == pytest.approx((0.06, 0.12))
    with pytest.raises(ValueError, match=r"margin=1.0 must be in \[0, 1\)"):
        margin_limits(0.05, 0.15, 1.0)

    def info(success, fraction, offset):
        return {
            "success": torch.tensor([success]),
            "refused": torch.tensor([False]),
            "target_fraction": torch.tensor([fraction]),
            "target_center_offset": torch.tensor([offset]),
        }

    edge, deep, off_centre = info(True, 0.055, 0.10), info(True, 0.07, 0.10), info(True, 0.07, 0.14)
    flags = [in_success_with_margin(i, 1, limits)[0] for i in (edge, deep, off_centre, info(False, 0.2, 0.0))]
    assert flags == [False, True, False, False]
    args = dqn.Args(success_bonus=1.0, hold_reward=0.2, step_cost=0.02, stay_penalty=0.1, hold_margin=0.2)
    reward = dqn.LearnerReward(args, 0.05, limits)
    reward.reset(info(False, 0.0, float("inf")))
    env_reward = torch.zeros(1)
    paid = [reward(env_reward, i, stayed=True) for i in (edge, edge, deep, off_centre)]
    # the first success earns the bonus wherever it is; after it, time and stays pay only well inside success
    assert paid == pytest.approx([0.88, -0.12, 0.18, -0.12])
    plain = dqn.LearnerReward(args, 0.05)  # no limits: every step in success pays, as before
    plain.reset(info(False, 0.0, float("inf")))
    assert [plain(env_reward, edge, stayed=True) for _ in range(2)] == pytest.approx([0.98, 0.18])
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=2), action_space=gym.spaces.Discrete(7))
    servo = ServoPolicy(env, hold=True, hold_limits=limits)  # the demonstrations' teacher
    both = {k: torch.cat([edge[k], deep[k]]) for k in edge}
    centred = np.array([[0.4, 0.4, 0.2, 0.2]] * 2, np.float32)
    assert servo.act(centred, both).tolist() == [mav.DIRECTIONS.index("forward"), STAY_INDEX]
    with pytest.raises(ValueError, match=r"margin=1.5 must be in \[0, 1\)"):
        dqn.train(dqn.Args(**{**dqn.HOLD, "hold_margin": 1.5}), progress=False)


def test_evaluate_takes_reference_steps_measured_before():
    env = BoxState(mav.DiscreteDirections(cached_task(start_pose="search", max_episode_steps=5)))
    servo = make_policy("servo", env)
    episodes = evaluate(env, servo, [1_000_000, 1_000_001], references={1_000_000: 3.0, 1_000_001: float("nan")})
    assert [e["reference_steps"] for e in episodes[:1]] == [3.0] and np.isnan(episodes[1]["reference_steps"])
    with pytest.raises(KeyError, match="no steps for seed 1000002"):  # an error, not a silent NaN
        evaluate(env, servo, [1_000_002], references={1_000_000: 3.0})
