"""Control: the DQN's pieces, the policies, the metrics and a short end-to-end training run."""

import dataclasses
import json
import math
import os
import re
import subprocess
import sys
import types

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import ROOT, cached_task

import mani_active_vision as mav
from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import (
    BACKWARD,
    CANDIDATE_BUDGET,
    CANDIDATE_MEMORY,
    DOWN,
    FORWARD,
    LEFT,
    LOOK_OVER,
    LOOK_OVER_TURN,
    POLICIES,
    RIGHT,
    STAY_INDEX,
    UP,
    DQNPolicy,
    ExplorePolicy,
    Sweep,
    make_policy,
    policy_kwargs,
    sweep_moves,
)
from mani_active_vision.agents.q_network import QNetwork, load_q_network, save_q_network
from mani_active_vision.box_state import BoxState
from mani_active_vision.envs import (
    DQN_BACK_WHEN_CLOSE,
    DQN_BOX_HOLD_DROP_CENTRED,
    DQN_EXPLORE_RESUMES_AFTER,
    DQN_FCN_CANDIDATE_THRESHOLD,
    DQN_FCN_THRESHOLDS,
    DQN_FINE_FROM_AREA,
    DQN_FINE_NEAR_CENTRE,
    DQN_FINE_STEP_SIZE,
    FCN_BOX_HOLD_STEPS,
    FCN_IMAGE_SIZE,
    FCN_SEGMENT_SIZE,
    EnvConfig,
)
from mani_active_vision.evaluation.cli import cli_with_preset_env
from mani_active_vision.evaluation.protocol import evaluate
from mani_active_vision.evaluation.report import markdown_table
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import Trajectory, episode_metrics, summarize


def _box_env(**kwargs):
    return BoxState(mav.DiscreteDirections(cached_task(**kwargs)))


def _batch(n=64, state_dim=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {
        "states": torch.rand(n, state_dim, generator=g),
        "actions": torch.randint(0, 6, (n,), generator=g),
        "rewards": torch.rand(n, generator=g),
        "next_states": torch.rand(n, state_dim, generator=g),
        "terminated": (torch.rand(n, generator=g) < 0.2).float(),
    }


@pytest.mark.parametrize("double_dqn,huber", [(False, False), (True, True)])
def test_dqn_update_lowers_the_td_error_on_a_fixed_batch(double_dqn, huber):
    torch.manual_seed(0)
    q_network, target_network = dqn.QNetwork(4), dqn.QNetwork(4)
    target_network.load_state_dict(q_network.state_dict())
    optimizer = torch.optim.Adam(q_network.parameters(), lr=1e-3)
    batch = _batch()
    before = dqn.td_loss(q_network, target_network, batch, 0.9, double_dqn, huber).item()
    for _ in range(200):
        loss = dqn.td_loss(q_network, target_network, batch, 0.9, double_dqn, huber)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert loss.item() < 0.5 * before


def test_td_target_uses_reward_discount_and_termination():
    q_network, target_network = dqn.QNetwork(4), dqn.QNetwork(4)
    for net, value in ((q_network, 0.0), (target_network, 2.0)):
        torch.nn.init.zeros_(net.network[2].weight)
        torch.nn.init.constant_(net.network[2].bias, value)
    batch = {
        "states": torch.zeros(2, 4),
        "actions": torch.tensor([0, 1]),
        "rewards": torch.tensor([1.0, 1.0]),
        "next_states": torch.zeros(2, 4),
        "terminated": torch.tensor([0.0, 1.0]),
    }
    # targets 1 + 0.5 * 2 = 2 and 1 (terminated); Q = 0: squared errors 4 and 1
    assert dqn.td_loss(q_network, target_network, batch, gamma=0.5).item() == pytest.approx(2.5)


def test_prioritised_replay_samples_by_td_error_and_weights_the_loss_back():
    buffer = dqn.ReplayBuffer(8, 4)
    for i in range(4):
        buffer.add(np.full(4, i), 0, 1.0, np.zeros(4), 0.0)
    rng = np.random.default_rng(0)
    assert "weights" not in buffer.sample(16, rng)  # α = 0: uniform, as without priorities
    buffer.set_priorities(torch.tensor([0, 1, 2]), torch.tensor([0.0, -0.99, 0.0]))  # |error| + PRIORITY_FLOOR
    assert buffer.priorities[:4].tolist() == pytest.approx([0.01, 1.0, 0.01, 1.0])  # 3 kept the first priority
    batch = buffer.sample(2000, rng, exponent=1.0, correction=1.0)
    share = np.bincount(batch["indices"].numpy(), minlength=4) / 2000
    assert share == pytest.approx([0.01 / 2.02, 1 / 2.02, 0.01 / 2.02, 1 / 2.02], abs=0.02)
    assert torch.equal(batch["states"][:, 0].long(), batch["indices"])  # each row is the transition it names
    weights = batch["weights"][torch.argsort(batch["indices"])]
    assert weights.max() <= 1 and weights.min() == pytest.approx(0.01)  # (N P)^-1, the rarest's at 1
    buffer.add(np.zeros(4), 0, 1.0, np.zeros(4), 0.0)  # a new transition: the largest priority so far
    assert buffer.priorities[4] == pytest.approx(1.0) and buffer.max_priority == pytest.approx(1.0)

    torch.manual_seed(0)
    q_network, target_network = dqn.QNetwork(4), dqn.QNetwork(4)
    plain = _batch()
    loss, errors = dqn.td_loss(q_network, target_network, plain, 0.9, with_errors=True)
    assert torch.equal(loss, dqn.td_loss(q_network, target_network, plain, 0.9))
    assert loss.item() == pytest.approx((errors**2).mean().item())
    weighted = {**plain, "weights": torch.linspace(0, 1, 64)}
    expected = (weighted["weights"] * errors**2).mean().item()
    assert dqn.td_loss(q_network, target_network, weighted, 0.9).item() == pytest.approx(expected)
    with pytest.raises(ValueError, match="prioritised replay is for one network"):
        dqn.train(dqn.Args(priority_exponent=0.6, ensemble=2, episodes=1))
    with pytest.raises(ValueError, match=r"priority_correction=1.5 in \[0, 1\]"):
        dqn.train(dqn.Args(priority_exponent=0.6, priority_correction=1.5, episodes=1))


@pytest.mark.parametrize("double_dqn", [False, True])
def test_an_ensembles_members_each_learn_against_their_own_target_and_it_acts_on_their_mean(double_dqn, tmp_path):
    torch.manual_seed(0)
    ensemble, target = dqn.QNetwork(4, 8, ensemble=3), dqn.QNetwork(4, 8, ensemble=3)
    alone = [dqn.QNetwork(4, 8) for _ in range(3)]  # each member as a network of its own
    targets = [dqn.QNetwork(4, 8) for _ in range(3)]
    for k in range(3):
        alone[k].network.load_state_dict(ensemble.members[k].state_dict())
        targets[k].network.load_state_dict(target.members[k].state_dict())
    batch = _batch()
    losses = [dqn.td_loss(alone[k], targets[k], batch, 0.9, double_dqn).item() for k in range(3)]
    assert dqn.td_loss(ensemble, target, batch, 0.9, double_dqn).item() == pytest.approx(np.mean(losses))
    batches = [_batch(seed=k) for k in range(3)]  # ensemble_batches: a batch of its own per member
    losses = [dqn.td_loss(alone[k], targets[k], batches[k], 0.9, double_dqn).item() for k in range(3)]
    assert dqn.td_loss(ensemble, target, batches, 0.9, double_dqn).item() == pytest.approx(np.mean(losses))
    values = torch.stack([net(batch["states"]) for net in alone])
    assert torch.allclose(ensemble.member_values(batch["states"]), values)
    assert torch.allclose(ensemble(batch["states"]), values.mean(0))
    save_q_network(str(tmp_path / "q.pt"), ensemble, dqn.Args(hidden_units=8, ensemble=3))
    loaded, config = load_q_network(str(tmp_path / "q.pt"))
    assert config["ensemble"] == 3 and torch.equal(loaded(batch["states"]), ensemble(batch["states"]))
    with pytest.raises(ValueError, match=r"ensemble=0 must be a positive integer"):
        dqn.QNetwork(4, ensemble=0)


def test_epsilon_schedule_is_linear_over_the_episodes():
    eps = [dqn.linear_schedule(0.1, 0.02, 99, t) for t in range(100)]
    assert eps[0] == pytest.approx(0.1) and eps[-1] == pytest.approx(0.02)
    assert np.allclose(np.diff(eps), -0.08 / 99)
    assert dqn.linear_schedule(0.1, 0.02, 99, 500) == pytest.approx(0.02)
    assert dqn.linear_schedule(0.1, 0.02, 0, 0) == 0.02


def test_servo_centres_then_approaches_and_its_sweep_turns_on_refusal():
    env = _box_env(start_pose="search")
    servo = make_policy("servo", env)
    servo.reset(None, {})
    act = lambda box, refused=False: int(servo.act(torch.tensor([box]), {"refused": torch.tensor([refused])})[0])  # noqa: E731
    assert act([0.4, 0.4, 0.2, 0.2]) == FORWARD  # centred
    assert act([0.0, 0.4, 0.2, 0.2]) == LEFT and act([0.8, 0.4, 0.2, 0.2]) == RIGHT
    assert act([0.4, 0.0, 0.2, 0.2]) == UP and act([0.4, 0.8, 0.2, 0.2]) == DOWN
    assert act([0, 0, 0, 0]) == LEFT  # unseen: sweep
    assert act([0, 0, 0, 0], refused=True) == RIGHT and act([0, 0, 0, 0]) == RIGHT


def test_exploration_hands_over_once_the_target_is_seen(tmp_path):
    env = _box_env(start_pose="search")
    q_network = dqn.QNetwork(4)
    torch.nn.init.zeros_(q_network.network[2].weight)
    with torch.no_grad():
        q_network.network[2].bias[:] = torch.tensor([0.0, 0, 0, 0, 0, 1])  # always "down"
    explore = ExplorePolicy(env, then=make_policy("dqn", env, q_network=q_network))
    unseen, seen = torch.zeros(1, 4), torch.tensor([[0.4, 0.4, 0.1, 0.1]])
    explore.reset(unseen, {})
    assert int(explore.act(unseen, {})[0]) == LEFT and not explore.handed_over[0]
    assert int(explore.act(seen, {})[0]) == DOWN and explore.handed_over[0]
    assert int(explore.act(unseen, {})[0]) == DOWN  # the hand-over holds for the rest of the episode
    explore.reset(unseen, {})
    assert int(explore.act(unseen, {})[0]) == LEFT
    with pytest.raises(ValueError, match="not one of"):
        make_policy("greedy", env)


def test_the_exploration_resumes_after_an_empty_box_where_the_env_says_so():
    env = mav.DiscreteDirections(cached_task(start_pose="search", obs_mode="rgb"), explore_resumes_after=3)
    explore = ExplorePolicy(
        env, then=types.SimpleNamespace(act=lambda obs, info: np.array([DOWN]), reset=lambda obs, info: None)
    )
    unseen, seen = torch.zeros(1, 4), torch.tensor([[0.4, 0.4, 0.1, 0.1]])
    explore.reset(unseen, {})
    acts = [int(explore.act(box, {})[0]) for box in (seen, unseen, unseen, unseen, unseen, seen)]
    assert acts == [DOWN, DOWN, DOWN, LEFT, LEFT, DOWN]  # 3 empty steps: the orbit again, until the next sighting
    assert ExplorePolicy(mav.DiscreteDirections(cached_task(start_pose="search", obs_mode="rgb"))).resumes_after == 0
    with pytest.raises(ValueError, match="explore_resumes_after=-1 must be an integer of at least 0"):
        mav.EnvConfig(explore_resumes_after=-1)


def test_the_track_bar_below_an_area_is_validated_and_reaches_the_box_state():
    with pytest.raises(ValueError, match=r"fcn_track_below_area=1.5 must be in \[0, 1\)"):
        EnvConfig(fcn_track_below_area=1.5)
    with pytest.raises(ValueError, match="fcn_track_below_area limits the verifier's track bar"):
        EnvConfig(box_source="fcn", fcn_track_below_area=0.05)  # no bars: nothing is tracked
    env = mav.DiscreteDirections(cached_task(start_pose="search", obs_mode="rgb"))
    with pytest.raises(ValueError, match="track_below_area=0.05 must be in"):
        BoxState(env, source="fcn", segmenter=object(), track_below_area=0.05)  # no bars
    config = EnvConfig(box_source="fcn", fcn_acquire_threshold=0.97, fcn_track_threshold=0.9, fcn_track_below_area=0.05)
    box_state = mav.envs.wrap_env(cached_task(start_pose="search", obs_mode="rgb"), config, segmenter=object())
    assert box_state.track_below_area == 0.05


def test_the_sweep_retraces_an_approach_before_it_orbits_on_where_the_env_says_so():
    """With `EnvConfig.sweep_retraces` the sweep first undoes the forward and up/down steps its owner took since it
    last orbited (fine moves count as their share of a step), a refused step is not counted, and a refused retrace
    step neither turns the orbit nor is tried again."""
    task = cached_task(start_pose="search", obs_mode="rgb")
    assert sweep_moves(mav.DiscreteDirections(task, fine_step=0.025)) is None  # off by default: the paper's sweep
    moves = sweep_moves(mav.DiscreteDirections(task, fine_step=0.025, sweep_retraces=True))
    names = mav.DiscreteDirections(task, fine_step=0.025).names
    assert moves[names.index("forward")].tolist() == [1, 0] and moves[names.index("down")].tolist() == [0, -1]
    assert moves[names.index("forward_fine")].tolist() == pytest.approx([0.025 / task.unwrapped.step_size, 0])
    assert moves[names.index("left")].tolist() == [0, 0]
    free, refused = {"refused": np.array([False])}, {"refused": np.array([True])}
    sweep = Sweep(1, moves=moves)

    def step(info, owner=None):  # the sweep's action, and the owner's (its own where None) counted
        action = sweep.act(info)
        sweep.moved(np.array([owner]) if owner is not None else action)
        return int(action[0])

    assert step(free, FORWARD) == LEFT  # the owner approaches: forward, up, and a forward that is refused
    assert step(free, UP) == BACKWARD
    assert step(free, FORWARD) == BACKWARD
    # the refused forward is taken back (and, as any refused step not the sweep's retrace, turns the orbit)
    assert [step(refused), step(free), step(free), step(free)] == [BACKWARD, DOWN, RIGHT, RIGHT]
    sweep.reset()
    step(free, FORWARD)
    assert [step(free), step(refused), step(free)] == [BACKWARD, LEFT, LEFT]  # blocked: the orbit on, not turned
    env = mav.DiscreteDirections(task, explore_resumes_after=2, sweep_retraces=True)
    explore = ExplorePolicy(
        env, then=types.SimpleNamespace(act=lambda obs, info: np.array([FORWARD]), reset=lambda obs, info: None)
    )
    unseen, seen = torch.zeros(1, 4), torch.tensor([[0.4, 0.4, 0.1, 0.1]])
    explore.reset(unseen, {})
    acts = [int(explore.act(box, free)[0]) for box in (seen, unseen, unseen, unseen, unseen, unseen)]
    assert acts == [FORWARD, FORWARD, BACKWARD, BACKWARD, LEFT, LEFT]  # the hand-over's approach undone, then orbit


def test_the_servo_and_the_exploration_approach_a_candidate_for_a_few_steps_within_a_budget():
    """Where the env reports a candidate (`info["candidate_box"]`, `EnvConfig.fcn_candidate_threshold`) and the box is
    empty, the servo serves it as it would the box, for `CANDIDATE_MEMORY` steps after the last report and at most
    `CANDIDATE_BUDGET` steps an episode; the exploration does so before its hand-over; without reports, nothing
    changes."""
    env = _box_env(start_pose="search")
    unseen = torch.zeros(1, 4)
    left_candidate = {"candidate_box": torch.tensor([[0.1, 0.45, 0.05, 0.05]])}
    nothing = {"candidate_box": torch.zeros(1, 4)}
    servo = make_policy("servo", env)
    servo.reset(None, {})
    acts = [int(servo.act(unseen, info)[0]) for info in [left_candidate] + [nothing] * (CANDIDATE_MEMORY + 1)]
    assert acts == [LEFT] * CANDIDATE_MEMORY + [LEFT, LEFT]  # toward it (left), then the sweep (left here too)
    servo.reset(None, {})
    right = {"candidate_box": torch.tensor([[0.85, 0.45, 0.05, 0.05]])}
    acts = [int(servo.act(unseen, right)[0]) for _ in range(CANDIDATE_BUDGET + 2)]
    assert acts == [RIGHT] * CANDIDATE_BUDGET + [LEFT, LEFT]  # the budget spent: the sweep again
    assert (
        int(servo.act(torch.tensor([[0.1, 0.45, 0.2, 0.2]]), right)[0]) == LEFT
    )  # a box seen: served, not the candidate
    servo.reset(None, {})
    assert int(servo.act(unseen, right)[0]) == RIGHT  # a new episode, a new budget
    then = types.SimpleNamespace(act=lambda obs, info: np.array([DOWN]), reset=lambda obs, info: None)
    assert ExplorePolicy(env, then=then).approach is None  # an env without candidates
    reporting = BoxState(
        mav.DiscreteDirections(cached_task(start_pose="search", obs_mode="rgb")),
        source="fcn",
        segmenter=object(),  # not called here: the policy is given the observations
        candidate_threshold=0.9,
    )
    explore = ExplorePolicy(reporting, then=then)
    explore.reset(unseen, {})
    centred = {"candidate_box": torch.tensor([[0.47, 0.47, 0.05, 0.05]])}
    acts = [int(explore.act(unseen, info)[0]) for info in (centred, nothing, nothing, nothing)]
    assert acts == [FORWARD] * CANDIDATE_MEMORY + [LEFT]  # centred: straight at it, then the orbit again
    assert int(explore.act(torch.tensor([[0.4, 0.4, 0.1, 0.1]]), centred)[0]) == DOWN  # seen: handed over
    explore.reset(unseen, {})
    assert int(explore.act(unseen, {})[0]) == LEFT  # no reports: the orbit


def test_every_policy_acts_in_the_action_space(tmp_path):
    env = _box_env(placement="random")
    checkpoint = str(tmp_path / "q.pt")
    save_q_network(checkpoint, dqn.QNetwork(4), dqn.Args())
    kwargs = {"dqn": {"checkpoint": checkpoint}, "explore": {"then": "dqn", "checkpoint": checkpoint}}
    for name in (n for n in POLICIES if n != "memory"):  # memory acts on a longer state: tests/test_search.py
        policy = make_policy(name, env, **kwargs.get(name, {}))
        obs, info = env.reset(seed=3)
        policy.reset(obs, info)
        for _ in range(3):
            action = policy.act(obs, info)
            assert action.shape == (1,) and action.dtype == np.int64 and env.action_space.contains(int(action[0])), name
            obs, _, _, _, info = env.step(action)
    with pytest.raises(ValueError, match="expects a state of 4"):
        make_policy(
            "dqn",
            BoxState(mav.DiscreteDirections(cached_task(placement="random")), with_ee_pos=True),
            checkpoint=checkpoint,
        )


def _trajectory(visible, success, target_fraction, rewards):
    t = Trajectory()
    t.visible, t.success, t.target_fraction, t.rewards = (
        list(visible),
        list(success),
        list(target_fraction),
        list(rewards),
    )
    return t


def test_metrics_on_hand_made_trajectories():
    # entry 0 is the reset; success first at step 3, lost at the end
    t = _trajectory([0, 0, 1, 1, 1], [0, 0, 0, 1, 0], [0, 0, 0.05, 0.12, 0.09], [0, 0.05, 0.12, 0.09])
    m = episode_metrics(t, reference_steps=2)
    assert m == {
        "success": 1.0,
        "success_final": 0.0,
        "focus_held": 0.5,  # in success at step 3, not at step 4
        "steps_to_see": 2.0,
        "steps_to_success": 3.0,
        "spl": pytest.approx(2 / 3),
        "final_target_fraction": 0.09,
        "return": pytest.approx(0.26),
    }
    assert episode_metrics(t, reference_steps=7)["spl"] == 1.0  # the agent's path is the shortest known
    assert math.isnan(episode_metrics(t)["spl"])  # no reference run: no SPL
    assert episode_metrics(t, reference_steps=math.nan)["spl"] == 1.0  # the reference failed: its own steps
    never = episode_metrics(_trajectory([1, 1], [0, 0], [0.01, 0.02], [0.02]), reference_steps=2)
    assert (
        never["success"] == 0
        and never["spl"] == 0
        and math.isnan(never["steps_to_success"])
        and math.isnan(never["focus_held"])
        and never["steps_to_see"] == 0
    )
    summary = summarize([m, never])
    assert summary["success"] == 0.5 and summary["steps_to_success"] == 3.0 and summary["steps_to_see"] == 1.0
    assert summary["focus_held"] == 0.5  # over the successful episode only
    assert "| a | 2 | 0.50 | 0.00 | 0.50 ± 0.00 |" in markdown_table({"a": summary})
    assert "| b | 1 | 0.00 | 0.00 | – |" in markdown_table({"b": summarize([never])})


def test_focus_held_is_the_share_in_success_from_the_first_success_on():
    def focus(success):
        return episode_metrics(_trajectory([1] * len(success), success, [0.1] * len(success), [0] * (len(success) - 1)))

    assert focus([0, 0, 1, 1, 1])["focus_held"] == 1.0  # found at step 2, never lost
    assert focus([0, 1, 0, 1, 0, 1])["focus_held"] == pytest.approx(3 / 5)  # oscillating in and out
    assert focus([0, 1, 0, 0, 0])["focus_held"] == pytest.approx(1 / 4)  # found, then lost for good
    assert focus([0, 0, 0, 0, 1])["focus_held"] == 1.0  # found at the last step (also success at the end)
    assert focus([1, 0])["focus_held"] == 0.5  # in success at the reset counts as found at step 0
    assert math.isnan(focus([0, 0, 0])["focus_held"])
    episodes = [focus([0, 1, 1, 1]), focus([0, 1, 0, 0, 0]), focus([0, 0])]
    summary = summarize(episodes)
    assert summary["focus_held"] == pytest.approx((1 + 1 / 4) / 2)  # the never-successful episode is left out
    assert summary["focus_held_std"] == pytest.approx(3 / 8)


def test_a_short_training_run_end_to_end(tmp_path):
    short = EnvConfig(max_episode_steps=40)  # short episodes: the same code, less time
    args = dqn.Args(
        env=short,
        episodes=2,
        learning_starts=20,
        target_update_steps=50,
        end_learning_rate=1e-4,
        ensemble=2,  # the other training runs here have one network
        ensemble_batches=True,
        run_dir=str(tmp_path),
    )
    result = dqn.train(args, progress=False)
    assert len(result["history"]) == 2 and result["history"][1]["epsilon"] == pytest.approx(0.02)
    assert [h["learning_rate"] for h in result["history"]] == pytest.approx([1e-3, 1e-4])  # decayed like ε
    with pytest.raises(ValueError, match="end_learning_rate=-0.1 must be ≥ 0"):
        dqn.train(dataclasses.replace(args, end_learning_rate=-0.1), progress=False)
    assert sum(h["learner_steps"] for h in result["history"]) > 0  # the target was seen, the DQN acted
    assert not math.isnan(result["history"][-1]["td_loss"])
    checkpoint = torch.load(result["checkpoint"], weights_only=True)
    assert checkpoint["config"]["hidden_units"] == 20 and checkpoint["config"]["state_dim"] == 4
    assert checkpoint["config"]["ensemble"] == 2 and "members.1.2.bias" in checkpoint["state_dict"]
    assert EnvConfig.from_dict(checkpoint["config"]["env"]) == short  # the checkpoint carries its env
    text = (tmp_path / "random_explore_seed0" / "history.json").read_text()
    history = json.loads(text, parse_constant=lambda name: pytest.fail(f"history.json holds {name}: not JSON"))
    assert history["complete"] and len(history["history"]) == 2
    env = _box_env(placement="random", max_episode_steps=40)
    policy = make_policy("explore", env, then="dqn", checkpoint=result["checkpoint"])
    episodes = evaluate(env, policy, [1_000_000], with_reference=False)
    assert set(episodes[0]) >= {"success", "spl", "steps_to_see", "return"}


def test_select_every_keeps_the_validated_network_that_succeeds_most(tmp_path, monkeypatch):
    """The saved network is the validated one with the best success (here the first of two checks, by a made-up
    score over real rollouts), on scenes of the run's range that training never reaches; training is unchanged."""
    short = EnvConfig(max_episode_steps=15)
    base = dict(env=short, episodes=4, learning_starts=5, target_update_steps=20)
    seen, snapshots, scores = [], [], iter([1.0, 0.0])

    def made_up_success(env, policy, seeds, **kwargs):
        seen.append(list(seeds))
        snapshots.append({k: v.clone() for k, v in policy.then.q_network.state_dict().items()})
        return [{**e, "success": next(scores)} for e in evaluate(env, policy, seeds, **kwargs)]

    monkeypatch.setattr(dqn, "evaluate", made_up_success)
    args = dqn.Args(**base, select_every=2, select_from=2, select_episodes=1, run_dir=str(tmp_path / "sel"))
    selected = dqn.train(args, progress=False)
    plain = dqn.train(dqn.Args(**base, run_dir=str(tmp_path / "plain")), progress=False)
    saved = torch.load(selected["checkpoint"], weights_only=True)["state_dict"]
    assert all(torch.equal(saved[k], snapshots[0][k]) for k in saved)  # the first check's, not the last network
    assert not all(torch.equal(snapshots[0][k], snapshots[1][k]) for k in saved)  # it learned in between
    last = torch.load(plain["checkpoint"], weights_only=True)["state_dict"]
    assert all(torch.equal(last[k], snapshots[1][k]) for k in last)  # validating changed nothing in training
    assert seen == [[dqn.VALIDATION_OFFSET]] * 2 and args.episodes <= dqn.VALIDATION_OFFSET
    history = json.loads((tmp_path / "sel" / "random_explore_seed0" / "history.json").read_text())
    assert [c["episodes"] for c in history["selection"]] == [2, 4] and history["selection"][0]["kept"]
    with pytest.raises(ValueError, match="select_every=-1"):
        dqn.train(dqn.Args(**base, select_every=-1, run_dir=str(tmp_path)), progress=False)


def test_prioritised_training_sets_priorities_from_its_updates(tmp_path, monkeypatch):
    base = dict(env=EnvConfig(max_episode_steps=15), episodes=2, learning_starts=5, target_update_steps=20)
    calls = []
    set_priorities = dqn.ReplayBuffer.set_priorities

    def recorded(buffer, indices, errors):
        calls.append(len(indices))
        set_priorities(buffer, indices, errors)
        calls.append(buffer.priorities[: buffer.size].copy())

    monkeypatch.setattr(dqn.ReplayBuffer, "set_priorities", recorded)
    result = dqn.train(dqn.Args(**base, priority_exponent=0.6, run_dir=str(tmp_path)), progress=False)
    assert calls and calls[0] == 32  # each update's batch
    assert len(set(np.round(calls[-1], 6))) > 2  # the TD errors, not the first priority, rank the transitions
    assert not math.isnan(result["history"][-1]["td_loss"])


def test_snapshots_average_the_last_networks_of_one_unchanged_training_run(tmp_path):
    """With snapshots=K the checkpoint is an ensemble of the network at the last K of every snapshot_every
    episodes: its last member is the network a plain run ends with (training is unchanged), an earlier one
    differs (it learned in between), and the agent acts on their mean."""
    base = dict(env=EnvConfig(max_episode_steps=15), episodes=4, learning_starts=5, target_update_steps=20)
    snapped = dqn.train(dqn.Args(**base, snapshots=2, snapshot_every=2, run_dir=str(tmp_path / "s")), progress=False)
    plain = dqn.train(dqn.Args(**base, run_dir=str(tmp_path / "p")), progress=False)
    ensemble, config = load_q_network(snapped["checkpoint"])
    last, _ = load_q_network(plain["checkpoint"])
    assert ensemble.ensemble == 2 and config["members"] == 2 and config["snapshots"] == 2
    assert all(torch.equal(a, b) for a, b in zip(ensemble.member(1).parameters(), last.parameters()))
    assert not all(torch.equal(a, b) for a, b in zip(ensemble.member(0).parameters(), last.parameters()))
    states = torch.randn(5, config["state_dim"])
    assert torch.allclose(ensemble(states), (ensemble.member(0)(states) + last(states)) / 2)
    for bad, match in [
        (dict(snapshots=0), "snapshots=0, snapshot_every=10: at least 1 each"),
        (dict(snapshots=3, snapshot_every=2), "reach before the first of the 4 training episodes"),
        (dict(snapshots=2, snapshot_every=2, ensemble=2), "cannot be combined with ensemble or select_every"),
    ]:
        with pytest.raises(ValueError, match=match):
            dqn.train(dqn.Args(**base, **bad, run_dir=str(tmp_path)), progress=False)


def test_track_writes_the_training_scalars_to_tensorboard(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    args = dqn.Args(
        env=EnvConfig(max_episode_steps=20), episodes=2, learning_starts=10, run_dir=str(tmp_path), track=True
    )
    result = dqn.train(args, progress=False)
    events = EventAccumulator(result["run_dir"]).Reload()
    assert {"charts/return", "charts/success", "charts/epsilon", "losses/td_loss"} <= set(events.Tags()["scalars"])
    returns = events.Scalars("charts/return")
    assert [e.value for e in returns] == pytest.approx([h["return"] for h in result["history"]])
    assert [e.step for e in returns] == [20, 40]  # CleanRL's x axis: the env steps so far
    assert [e.value for e in events.Scalars("charts/epsilon")] == pytest.approx([0.1, 0.02])
    assert os.path.exists(os.path.join(result["run_dir"], "history.json"))  # the history as without --track


def test_track_without_tensorboard_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # importing it now fails
    with pytest.raises(ImportError, match=re.escape("pip install -e '.[track]'")):
        dqn.train(dqn.Args(run_dir=str(tmp_path), track=True), progress=False)
    assert not any(name.endswith("q_network.pt") for _, _, files in os.walk(tmp_path) for name in files)


def test_margin_loss_is_zero_once_the_demonstrators_action_leads_by_the_margin():
    q_network = dqn.QNetwork(4, 8, 6)
    with torch.no_grad():  # Q = the bias: action 2 leads every other by 1
        q_network.network[2].weight.zero_()
        q_network.network[2].bias.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
    batch = {"states": torch.rand(4, 4), "actions": torch.tensor([2, 2, 0, 5]), "demo": torch.tensor([1, 1, 1, 0]) > 0}
    # demonstrations 2 and 2 lead by 1 >= 0.8: no loss; demonstration 0 trails action 2 by 1, plus the margin
    assert dqn.margin_loss(q_network, batch, 0.8).item() == pytest.approx((0 + 0 + 1.8) / 3)
    assert dqn.margin_loss(q_network, {**batch, "demo": torch.zeros(4, dtype=torch.bool)}, 0.8).item() == 0


def test_the_margin_only_on_a_demonstrations_first_steps():
    args = dqn.Args(demo_margin=0.8, demo_margin_steps=2)
    window, marked = dqn.NStepWindow(n=3, gamma=0.9), {}
    for step in range(6):  # as train() stores them: 3-step transitions, the tails flushed at the episode's end
        for first, *_, steps in window.push(step, 0, 0.0, step + 1, False, step == 5):
            marked[first] = dqn.margin_applies(args, True, step, steps)
    assert marked == {0: True, 1: True, 2: False, 3: False, 4: False, 5: False}
    assert not dqn.margin_applies(args, False, 2, 3)  # the learner's own steps never
    assert dqn.margin_applies(dqn.Args(demo_margin=0.8), True, 60, 3)  # 0: every demonstration step
    with pytest.raises(ValueError, match="demo_margin_steps=-1"):
        dqn.train(dqn.Args(demo_margin_steps=-1), progress=False)


def test_the_holding_servo_stays_in_success_only():
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=2), action_space=gym.spaces.Discrete(7))
    servo = make_policy("servo", env, hold=True)
    centred_and_close = np.array([[0.35, 0.35, 0.3, 0.3], [0.35, 0.35, 0.3, 0.3]])
    action = servo.act(centred_and_close, {"success": np.array([True, False]), "refused": np.zeros(2, bool)})
    assert action.tolist() == [6, FORWARD]  # stay where the task says success, else the servo's step
    with pytest.raises(ValueError, match="stay_action"):
        make_policy(
            "servo", types.SimpleNamespace(unwrapped=env.unwrapped, action_space=gym.spaces.Discrete(6)), hold=True
        )


def test_the_look_over_sweep_turns_at_the_placement_range_once_or_at_a_refusal():
    free, refused = {"refused": np.array([False])}, {"refused": np.array([True])}
    sweep = Sweep.looking_over(1)
    actions = [int(sweep.act(free)[0]) for _ in range(len(LOOK_OVER) + LOOK_OVER_TURN + 3)]
    orbit = actions[len(LOOK_OVER) :]
    assert orbit == [LEFT] * LOOK_OVER_TURN + [RIGHT] * 3  # turned after LOOK_OVER_TURN orbit steps
    assert int(sweep.act(refused)[0]) == LEFT  # then a refusal (joint 1's limit) turns it as before
    sweep.reset()
    for _ in range(len(LOOK_OVER) + 2):
        sweep.act(free)
    assert int(sweep.act(refused)[0]) == RIGHT  # refused before the first turn: turned once, not again
    assert [int(sweep.act(free)[0]) for _ in range(LOOK_OVER_TURN)] == [RIGHT] * LOOK_OVER_TURN


def test_the_look_over_servo_approaches_from_above_backs_off_and_does_not_repeat_a_refusal():
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(6))
    servo = make_policy("servo", env, look_over=True, lead_in=False)
    plain = make_policy("servo", env)
    free, refused = {"refused": np.array([False])}, {"refused": np.array([True])}

    def act(policy, box, info=free):
        return int(policy.act(np.array([box], np.float32), info)[0])

    small_and_low = [0.45, 0.62, 0.1, 0.1]  # centre row 0.67: the plain servo centres it, this one comes closer
    assert act(plain, small_and_low) == DOWN and act(servo, small_and_low) == FORWARD
    near_and_low = [0.35, 0.55, 0.3, 0.3]  # once near, it is centred
    assert act(servo, near_and_low) == DOWN
    assert act(servo, [0.0, 0.1, 1.0, 0.8]) == BACKWARD  # spans the image: too close
    servo.reset(None, None)
    assert act(servo, small_and_low) == FORWARD
    assert act(servo, small_and_low, refused) == UP  # the forward step was refused: up, not forward again
    assert act(servo, [0.25, 0.5, 0.1, 0.1]) == LEFT
    right_of_centre = [0.6, 0.5, 0.1, 0.1]
    assert act(plain, right_of_centre) == RIGHT
    assert act(servo, right_of_centre) == FORWARD  # not straight back across the target after a left step
    assert act(make_policy("servo", env, look_over=True), small_and_low) == LOOK_OVER[0]  # with the lead-in first


def test_the_look_over_servo_retreats_level_from_a_near_target_low_in_the_image():
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(6))
    servo = make_policy("servo", env, look_over=True, lead_in=False)
    free, refused = {"refused": np.array([False])}, {"refused": np.array([True])}

    def act(box, info=free):
        return int(servo.act(np.array([box], np.float32), info)[0])

    near_and_low = [0.25, 0.5, 0.5, 0.45]  # covers 0.225, centre row 0.725: a step down alone would cut it
    centred = [0.3, 0.42, 0.4, 0.35]  # what the step back shows: centred, so alone it would be approached
    assert act(near_and_low) == BACKWARD  # back and up along the pitched axis...
    assert act(centred) == DOWN  # ...then down: level, away from the target
    assert act(centred) == FORWARD  # the retreat done, it approaches again
    assert act(near_and_low) == BACKWARD
    assert act(near_and_low, refused) == DOWN  # the step back refused (a panel behind): down
    assert act(near_and_low) == BACKWARD
    servo.last_action[:] = FORWARD  # a learner asking the servo (agents.search.ServoTeacher) did not step back
    assert act(centred) == FORWARD  # so no retreat to finish


def test_policy_kwargs_look_over_reaches_the_servo_and_the_exploration_and_names_a_wrong_pairing():
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(6))
    servo = make_policy("servo", env, **policy_kwargs("servo", look_over=True))
    explore = make_policy("explore", env, **policy_kwargs("explore", look_over=True))
    assert servo.look_over and list(servo.sweep.lead_in) == list(LOOK_OVER)
    assert list(explore.sweep.lead_in) == list(LOOK_OVER)
    assert len(make_policy("explore", env, **policy_kwargs("explore")).sweep.lead_in) == 0
    for name, then in (("random", "none"), ("explore", "servo")):
        with pytest.raises(ValueError, match=f"not policy '{name}' then '{then}'"):
            policy_kwargs(name, then, look_over=True)


def test_the_dqns_demonstrating_servo_approaches_from_above_without_redoing_the_lead_in(monkeypatch, tmp_path):
    made = []

    class Recorded(dqn.ServoPolicy):
        def __init__(self, env, **kwargs):
            made.append(kwargs)
            super().__init__(env, **kwargs)

    monkeypatch.setattr(dqn, "ServoPolicy", Recorded)
    args = dqn.Args(look_over=True, demo_episodes=1, episodes=1, env=EnvConfig(max_episode_steps=2))
    dqn.train(dataclasses.replace(args, run_dir=str(tmp_path)), progress=False)
    assert made[0]["look_over"] and not made[0]["lead_in"]  # the exploration has looked over before it hands over


def test_batched_training_plays_the_same_episodes_as_one_env(tmp_path):
    # two demonstration episodes: what happens in them does not depend on the network, so one env and two
    # worker processes (one episode each, at once) must give the same episodes and the same transitions
    args = dqn.Args(**dqn.HOLD, demo_episodes=2, env=EnvConfig(max_episode_steps=15), episodes=2, run_dir=str(tmp_path))
    one, two = (dqn.train(dataclasses.replace(args, num_envs=n, run_name=f"n{n}"), progress=False) for n in (1, 2))
    keys = ("episode", "demo", "epsilon", "learner_steps", "learner_return", "return", "final_target_fraction")
    assert [[h[k] for k in keys] for h in two["history"]] == [[h[k] for k in keys] for h in one["history"]]
    assert two["transitions"] == one["transitions"] > 0
    with pytest.raises(ValueError, match="must be a multiple of num_envs=2"):
        dqn.train(dataclasses.replace(args, episodes=3, num_envs=2), progress=False)


def test_avoid_refused_does_not_repeat_a_refused_action_at_once(tmp_path):
    stand_in = types.SimpleNamespace(
        unwrapped=types.SimpleNamespace(num_envs=1),
        action_space=gym.spaces.Discrete(6),
        observation_space=gym.spaces.Box(0.0, 1.0, (1, 4)),
    )
    q_network = QNetwork(4, 8, 6)
    with torch.no_grad():  # Q = 0, 1, ..., 5 whatever the state: the greedy action is 5, then 4
        q_network.network[2].weight.zero_()
        q_network.network[2].bias.copy_(torch.arange(6.0))
    box, refused = np.full((1, 4), 0.3, np.float32), {"refused": torch.tensor([True])}
    path = str(tmp_path / "q_network.pt")
    save_q_network(path, q_network, dqn.Args(hidden_units=8, avoid_refused=True))
    wary = DQNPolicy(stand_in, checkpoint=path)  # the option comes with the checkpoint
    plain = DQNPolicy(stand_in, q_network=q_network)
    for policy in (wary, plain):
        policy.reset(box, {})
    assert wary.act(box, {})[0] == 5 and wary.act(box, refused)[0] == 4  # 5 was refused: the next best
    assert wary.act(box, refused)[0] == 5  # only the action just refused is left out
    assert plain.act(box, {})[0] == 5 and plain.act(box, refused)[0] == 5  # without the option it repeats


def test_the_shipped_dqn_loads_and_acts_as_deployed():
    path = os.path.join(ROOT, "agents", "weights", "dqn.pt")
    config = torch.load(path, weights_only=True)["config"]  # weights and plain data only
    deployed, trained = EnvConfig.from_dict(config["env"]), EnvConfig.from_dict(config["trained_env"])
    assert (deployed.box_source, deployed.object_set, deployed.image_size) == ("fcn", "unseen", FCN_IMAGE_SIZE)
    assert trained.box_source == "ground_truth"  # evaluate.py starts from the deployed env
    acquire, track = DQN_FCN_THRESHOLDS  # the verifier's bars it is deployed with
    assert deployed == trained.replace(
        box_source="fcn",
        object_set="unseen",
        image_size=FCN_IMAGE_SIZE,
        box_hold_steps=FCN_BOX_HOLD_STEPS,
        fcn_acquire_threshold=acquire,
        fcn_track_threshold=track,
        fcn_segment_size=FCN_SEGMENT_SIZE,  # the network segments the camera's own 128² (docs/control.md §17)
        fine_near_centre=DQN_FINE_NEAR_CENTRE,  # the fine moves only close to the centre (docs/control.md §18)
        fine_from_area=DQN_FINE_FROM_AREA,  # and only once the box covers 4.5% of the image (§32)
        back_when_close=DQN_BACK_WHEN_CLOSE,  # a step back when pushed too close (docs/control.md §19)
        stay_needs_success=True,  # stay only where the mask stats say success (docs/control.md §21)
        box_hold_follows_camera=True,  # the held box moves with the camera (docs/control.md §25)
        box_hold_drop_centred=DQN_BOX_HOLD_DROP_CENTRED,  # and is dropped once centred, unseen (docs/control.md §27)
        fcn_border_bar_near_box=True,  # the border's low bar only near the tracked box (docs/control.md §30)
        explore_resumes_after=DQN_EXPLORE_RESUMES_AFTER,  # the orbit again after an empty box (docs/control.md §31)
        fcn_candidate_threshold=DQN_FCN_CANDIDATE_THRESHOLD,  # near-misses approached (docs/control.md §34)
    )
    assert deployed == trained.as_dqn_deployed().replace(object_set="unseen")  # ship_dqn.py --as-dqn
    # the hold_stay_fine preset: it stays well inside success, sees the mask stats, does not repeat a refused
    # action, its learning rate was decayed, and it learnt with the half steps near the target it takes deployed
    assert trained.fine_step_size == DQN_FINE_STEP_SIZE and config["fine_as_deployed"]
    assert deployed.stay_action and deployed.with_mask_stats and config["hold_margin"] == 0.15
    assert config["avoid_refused"] and config["hidden_units"] == 128 and config["end_learning_rate"] == 1e-4
    env = mav.make_env(deployed.replace(max_episode_steps=25))
    try:
        policy = make_policy("explore", env, then="dqn", checkpoint=path)
        episode = evaluate(env, policy, [1_000_000], with_reference=False)[0]
    finally:
        env.close()
    assert policy.handed_over.all() and policy.then.last_action[0] >= 0  # the target was seen and the DQN acted
    assert episode["steps_to_see"] < 25


def test_the_shipped_ensemble_is_five_runs_of_the_shipped_preset_deployed_as_dqn_pt():
    weights = os.path.join(ROOT, "agents", "weights")
    ensemble, config = load_q_network(os.path.join(weights, "dqn_ensemble.pt"))
    single, single_config = load_q_network(os.path.join(weights, "dqn.pt"))
    assert (ensemble.ensemble, config["member_seeds"], config["member_episodes"]) == (5, [0, 1, 2, 3, 4], 500)
    for key in ("env", "trained_env", "hidden_units", "fine_as_deployed", "hold_margin"):
        assert config[key] == single_config[key]  # the same preset, trained and deployed alike
    for name, tensor in single.network.state_dict().items():  # seed 0's run is dqn.pt's
        assert torch.equal(ensemble.member(0).state_dict()[name], tensor)
    state = torch.randn(8, ensemble.state_dim)
    means = torch.stack([ensemble.member(k)(state) for k in range(5)]).mean(0)
    torch.testing.assert_close(ensemble(state), means)  # it acts on the mean Q
    env = mav.make_env(EnvConfig.from_dict(config["env"]).replace(max_episode_steps=25))
    try:
        policy = make_policy("explore", env, then="dqn", checkpoint=os.path.join(weights, "dqn_ensemble.pt"))
        episode = evaluate(env, policy, [1_000_000], with_reference=False)[0]
    finally:
        env.close()
    assert policy.handed_over.all() and policy.then.last_action[0] >= 0 and episode["steps_to_see"] < 25


def test_several_runs_ship_as_one_agent_acting_on_their_mean_q(baseline_script, tmp_path):
    ship_dqn = baseline_script("ship_dqn")
    trained = EnvConfig(stay_action=True, with_mask_stats=True)
    paths, networks = [], []
    for seed, hidden in ((0, 16), (1, 16), (2, 8)):
        torch.manual_seed(seed)
        networks.append(QNetwork(7, hidden, 7))
        paths.append(str(tmp_path / f"seed{seed}.pt"))
        save_q_network(paths[-1], networks[-1], dqn.Args(env=trained, seed=seed, hidden_units=hidden))
    out = str(tmp_path / "ensemble.pt")
    deployed = ship_dqn.ship(ship_dqn.Args(checkpoint=paths[0], members=(paths[1],), out=out))
    ensemble, config = load_q_network(out)  # loads as any checkpoint does, weights_only
    state = torch.randn(5, 7)
    torch.testing.assert_close(ensemble(state), (networks[0](state) + networks[1](state)) / 2)
    assert (ensemble.ensemble, config["member_seeds"], config["member_episodes"]) == (2, [0, 1], 200)
    assert deployed.box_source == "fcn" and EnvConfig.from_dict(config["trained_env"]) == trained
    with pytest.raises(ValueError, match=r"seed2.pt' differs from .*seed0.pt' in hidden_units: 8 != 16"):
        ship_dqn.ship(ship_dqn.Args(checkpoint=paths[0], members=(paths[2],), out=out))


def test_seeds_set_changes_options_of_the_preset_and_names_a_wrong_one(baseline_script):
    seeds = baseline_script("seeds")
    args = seeds.Args(preset="hold_demo", set=["demo_episodes=20", "demo_margin=0.8", "double_dqn=false"])
    assert seeds.train_options(args) == {"demo_episodes": 20, "demo_margin": 0.8, "double_dqn": False}
    assert seeds.label(args) == "hold_demo" and seeds.label(dataclasses.replace(args, name="x")) == "x"
    with pytest.raises(ValueError, match="'seed' is not one of"):  # the script's own, not the preset's
        seeds.train_options(dataclasses.replace(args, set=["seed=3"]))
    # the preset's env is the default of --env.*: hold_stay acts with stay and the mask stats; a flag overrides
    stays = cli_with_preset_env(seeds.Args, ["--preset", "hold_stay"]).env
    assert stays == dqn.PRESETS["hold_stay"][1].env and stays.stay_action and stays.with_mask_stats
    assert not cli_with_preset_env(seeds.Args, ["--preset", "hold_stay", "--env.no-stay-action"]).env.stay_action
    assert cli_with_preset_env(seeds.Args, ["--preset", "hold_demo_wide"]).env == EnvConfig()
    with pytest.raises(ValueError, match="preset='x' is not one of: paper"):
        cli_with_preset_env(seeds.Args, ["--preset", "x"])
    # a preset trained with the fine moves is evaluated with them unless told otherwise, and its files say so
    fine = cli_with_preset_env(seeds.Args, ["--preset", "hold_stay_fine"])
    assert seeds.eval_env_config(fine).fine_step_size == DQN_FINE_STEP_SIZE and seeds.eval_suffix(fine) == "_fine"
    full = cli_with_preset_env(seeds.Args, ["--preset", "hold_stay_fine", "--eval-fine-step-size", "0"])
    assert seeds.eval_env_config(full).fine_step_size == 0 and seeds.eval_suffix(full) == ""
    decay = cli_with_preset_env(seeds.Args, ["--preset", "hold_stay_decay", "--eval-fine-step-size", "0.025"])
    assert seeds.eval_env_config(decay).fine_step_size == 0.025 and decay.env.fine_step_size == 0  # training: full step


def test_seeds_does_not_reuse_an_evaluation_taken_in_another_env(baseline_script, tmp_path):
    seeds = baseline_script("seeds")
    flags = ["--preset", "hold_stay_fine", "--out-dir", str(tmp_path), "--seeds", "0", "--eval-box-source", "fcn"]
    args = cli_with_preset_env(seeds.Args, [*flags, "--env.fcn-segment-size", "128"])
    seed_dir = tmp_path / "hold_stay_fine" / "seed0"
    seed_dir.mkdir(parents=True)
    (seed_dir / "history.json").write_text(json.dumps({"complete": True, "seconds": 1.0, "history": [{"success": 1}]}))
    summary = {key: 0.5 for key in seeds.COLUMNS}
    taken = dataclasses.replace(args, env=args.env.replace(fcn_segment_size=0))  # dqn_seeds.sh's flags before §17
    save_json(
        {"eval_env": dataclasses.asdict(seeds.eval_env_config(taken)), "summary": summary},
        seeds.eval_path(args, str(seed_dir)),
    )
    with pytest.raises(ValueError, match=r"another env \(fcn_segment_size: 0 != 128\): choose another --out-dir"):
        seeds.run_seed(args, 0)  # neither trained again nor evaluated: the run is finished
    with pytest.raises(ValueError, match="fcn_segment_size: 0 != 128"):
        seeds.report(args)
    assert "| hold_stay_fine seed0 | 1 |" in seeds.report(taken)  # in the env it was taken in, it is the table's
    seeds.run_seed(taken, 0)  # and is not taken again


def test_focus_curve_gives_the_share_in_success_per_step_and_plots_it(baseline_script, monkeypatch, tmp_path):
    focus_curve = baseline_script("focus_curve")
    shipped = os.path.join(ROOT, "agents", "weights", "dqn.pt")
    args = focus_curve.Args(agents=[], episodes=2, box_source="ground_truth")
    share = focus_curve.in_success(shipped, args)
    assert len(share) == 100 and set(share) <= {0.0, 0.5, 1.0}  # after each of 100 steps, over 2 episodes
    assert share[0] == 0.0  # the first step is the exploration's, from the sky start: no success yet
    out = str(tmp_path / "focus.png")
    monkeypatch.setattr(focus_curve, "in_success", lambda checkpoint, args: share)
    (tmp_path / "agent" / "seed0").mkdir(parents=True)
    (tmp_path / "agent" / "seed0" / "q_network.pt").touch()
    curves = focus_curve.main(focus_curve.Args(agents=[f"x={tmp_path / 'agent'}"], out=out))
    assert curves == {"x": [share]} and os.path.getsize(out) > 0
    with pytest.raises(ValueError, match="each must be label=folder"):
        focus_curve.main(focus_curve.Args(agents=["x"], out=out))


def test_mirrored_transitions_and_shaping_potentials():
    six = dqn.mirrored_actions(6)  # the table of the six directions
    assert [mav.DIRECTIONS[a] for a in six] == ["right", "left", "forward", "backward", "up", "down"]
    np.testing.assert_allclose(dqn.mirror_state(np.array([0.1, 0.2, 0.3, 0.4])), [0.6, 0.2, 0.3, 0.4])
    assert not dqn.mirror_state(np.zeros(4)).any()  # unseen stays unseen
    last_left = np.array([0.1, 0.2, 0.3, 0.4, 1, 0, 0, 0, 0, 0])  # with the last direction: left -> right
    np.testing.assert_allclose(dqn.mirror_state(last_left), [0.6, 0.2, 0.3, 0.4, 0, 1, 0, 0, 0, 0])

    def info(fraction):
        return {"target_fraction": torch.tensor([fraction])}

    assert dqn.potential(info(0.02), 0.05, "none") == 0.0
    assert dqn.potential(info(0.02), 0.05, "fraction") == pytest.approx(0.4)
    assert dqn.potential(info(0.2), 0.05, "fraction") == 1.0
    fractions = (0.0, 0.0005, 0.005, 0.05, 0.5)
    assert [dqn.potential(info(f), 0.05, "log_fraction") for f in fractions] == pytest.approx(
        [0, 0, 0.5, 1, 1], abs=1e-6
    )
    seen = {"target_fraction": torch.tensor([0.005]), "target_center_offset": torch.tensor([0.1])}
    assert dqn.potential(seen, 0.05, "log_fraction_centred") == pytest.approx(0.5 * (0.5 + 0.8))
    unseen = {"target_fraction": torch.tensor([0.0]), "target_center_offset": torch.tensor([float("inf")])}
    assert dqn.potential(unseen, 0.05, "log_fraction_centred") == 0.0
    with pytest.raises(ValueError, match="shaping='loud' is not one of"):
        dqn.train(dqn.Args(shaping="loud"), progress=False)


def test_a_short_shaped_training_run_stores_mirrored_transitions(tmp_path):
    args = dqn.Args(
        **dqn.SHAPED, env=EnvConfig(max_episode_steps=40), episodes=2, learning_starts=20, run_dir=str(tmp_path)
    )
    result = dqn.train(args, progress=False)
    learner_steps = sum(h["learner_steps"] for h in result["history"])
    assert learner_steps > 0 and result["transitions"] == 2 * learner_steps
    config = torch.load(result["checkpoint"], weights_only=True)["config"]
    assert {k: config[k] for k in dqn.SHAPED} == dqn.SHAPED and config["state_dim"] == 4 + 6  # box + last direction
    with_presence = dqn.train(dataclasses.replace(args, env=args.env.replace(with_presence=True)), progress=False)
    config = torch.load(with_presence["checkpoint"], weights_only=True)["config"]
    assert config["state_dim"] == 4 + 1 + 6  # box, presence, last direction; mirrored with the score in place
    assert with_presence["transitions"] == 2 * sum(h["learner_steps"] for h in with_presence["history"])


def test_ending_cycle_finds_the_period_of_the_last_actions(baseline_script):
    counts = baseline_script("action_counts")
    assert counts.ending_cycle([2] * 30 + [4, 5] * 10) == 2  # up, down, up, down, ...
    assert counts.ending_cycle([0, 1, 2, 3, 4] * 6) is None  # a period of 5 is not a cycle here
    assert counts.ending_cycle([3] * 25) == 1
    assert counts.ending_cycle([4, 5] * 9) is None  # shorter than CYCLE_STEPS
    assert counts.ending_cycle([0, 4, 1, 5] * 5 + [0, 4]) == 4


def test_box_dropout_hides_the_box_of_the_dropped_envs_only():
    obs = torch.tensor([[0.5, 0.4, 0.1, 0.2, 0.3, 0.0, 0.6], [0.2, 0.2, 0.3, 0.3, 0.1, 0.1, 0.5]])
    dropped = dqn.drop_boxes(obs, np.array([True, False]))
    assert dropped[0].tolist() == pytest.approx([0, 0, 0, 0, 0.3, 0.0, 0.6])  # the camera's position is kept
    assert dropped[1].tolist() == pytest.approx(obs[1].tolist())
    assert dqn.drop_boxes(obs, np.array([False, False])) is obs
    with pytest.raises(ValueError, match=r"box_dropout=1.0 must be a probability in \[0, 1\)"):
        dqn.train(dqn.Args(box_dropout=1.0), progress=False)


def test_a_training_push_forces_one_direction_after_the_first_success(tmp_path, monkeypatch):
    taken, success = [], []
    make_env = dqn.make_env

    def recorded_env(config):  # the actions the env is given and the success they led to
        env = make_env(config)
        step = env.step

        def record(action):
            taken.append(int(np.asarray(action).reshape(-1)[0]))
            result = step(action)
            success.append(bool(np.asarray(result[-1]["success"]).reshape(-1)[0]))
            return result

        env.step = record
        return env

    monkeypatch.setattr(dqn, "make_env", recorded_env)
    # the holding servo acts in the learner's place, so that the episode reaches success and stays there
    monkeypatch.setattr(dqn.DemoOrLearner, "act", lambda self, obs, info: self.servo.act(obs, info))
    env = EnvConfig(stay_action=True, with_mask_stats=True, max_episode_steps=60)
    args = dqn.Args(**{**dqn.HOLD, "env": env}, episodes=1, push_probability=1.0, push_steps=4, run_dir=str(tmp_path))
    (episode,) = dqn.train(args, progress=False)["history"]
    assert episode["pushed"] and True in success
    first = success.index(True)
    push = taken[first + 1 : first + 5]
    assert len(set(push)) == 1 and push[0] != STAY_INDEX  # four steps of one direction; the servo would stay
    assert taken[first + 5 :] and STAY_INDEX in taken[first + 5 :]  # then the servo acts again
    with pytest.raises(ValueError, match=r"push_probability=1.5, push_steps=6: a probability in \[0, 1\]"):
        dqn.train(dqn.Args(push_probability=1.5), progress=False)


def test_dqn_policy_with_last_action_sees_its_own_previous_direction():
    env = _box_env(placement="fixed")
    obs, info = env.reset(seed=0)
    policy = make_policy("dqn", env, q_network=dqn.QNetwork(4 + 6), with_last_action=True)
    policy.reset(obs, info)
    assert policy.state(obs).shape == (1, 10) and not policy.state(obs)[0, 4:].any()
    action = policy.act(obs, info)
    one_hot = policy.state(obs)[0, 4:]
    assert one_hot.sum() == 1 and one_hot[action[0]] == 1
    with pytest.raises(ValueError, match="expects a state of 4 numbers"):
        make_policy("dqn", env, q_network=dqn.QNetwork(4), with_last_action=True)


def test_n_step_window_sums_discounted_rewards_and_flushes_at_the_end():
    window = dqn.NStepWindow(n=3, gamma=0.5)
    assert window.push("s0", 0, 1.0, "s1", False, False) == [] and window.push("s1", 1, 2.0, "s2", False, False) == []
    assert window.push("s2", 2, 4.0, "s3", False, False) == [("s0", 0, 1 + 0.5 * 2 + 0.25 * 4, "s3", False, 3)]
    tails = window.push("s3", 3, 8.0, "s4", True, True)  # the episode ends: every pending step is flushed
    assert tails == [
        ("s1", 1, 2 + 0.5 * 4 + 0.25 * 8, "s4", True, 3),
        ("s2", 2, 4 + 0.5 * 8, "s4", True, 2),
        ("s3", 3, 8.0, "s4", True, 1),
    ]
    assert window.pending == []
    batch = {
        "states": torch.zeros(2, 4),
        "actions": torch.zeros(2, dtype=torch.long),
        "rewards": torch.tensor([1.0, 1.0]),
        "next_states": torch.zeros(2, 4),
        "terminated": torch.zeros(2),
        "steps": torch.tensor([1.0, 3.0]),
    }
    q = dqn.QNetwork(4)
    with torch.no_grad():
        value = q(torch.zeros(1, 4)).max().item()
        expected = torch.tensor([1 + 0.9 * value, 1 + 0.9**3 * value])
        q_sa = q(torch.zeros(2, 4))[:, 0]
    assert dqn.td_loss(q, q, batch, 0.9).item() == pytest.approx(torch.nn.functional.mse_loss(q_sa, expected).item())


def test_evaluate_script_writes_focus_held_to_its_json(tmp_path):
    path = tmp_path / "evaluate.json"
    command = [sys.executable, os.path.join(ROOT, "baselines", "evaluate.py"), "--policy", "servo", "--episodes", "2"]
    command += ["--no-reference", "--env.max-episode-steps", "40", "--env.start-pose", "search", "--json", str(path)]
    subprocess.run(command, cwd=ROOT, check=True, capture_output=True)
    result = json.loads(path.read_text())
    for episode in result["episodes"]:  # null exactly when the episode never succeeded
        assert (episode["focus_held"] is None) == (episode["success"] == 0)
        assert episode["focus_held"] is None or 0 < episode["focus_held"] <= 1
    held = [e["focus_held"] for e in result["episodes"] if e["focus_held"] is not None]
    assert result["summary"]["focus_held"] == (pytest.approx(np.mean(held)) if held else None)


def test_servo_demonstrations_fill_the_buffer_before_the_dqn_acts(tmp_path):
    args = dqn.Args(
        **dqn.SHAPED,
        demo_episodes=1,
        env=EnvConfig(max_episode_steps=40),
        episodes=2,
        learning_starts=20,
        run_dir=str(tmp_path),
    )
    result = dqn.train(args, progress=False)
    first, second = result["history"]
    assert first["demo"] and not second["demo"]
    assert first["learner_steps"] > 0  # the servo's steps after the hand-over are stored as the learner's
    assert result["transitions"] == 2 * (first["learner_steps"] + second["learner_steps"])  # mirrored too


def test_box_failures_sorts_a_lost_episode_by_what_the_box_lay_on(baseline_script):
    failures = baseline_script("box_failures")

    def steps(*pairs):  # (target pixels in view, what the box lies on: slot + 1, 0 floor, None no box)
        return [dict(target_px=px, on=on, presence=0.9) for px, on in pairs]

    assert failures.classify(steps((0, 3), (0, 3), (30, 1), (40, 3))) == "on a look-alike"
    assert failures.classify(steps((0, None), (25, None), (30, None), (40, 1))) == "target missed"
    assert failures.classify(steps((0, None), (25, 1), (30, 1), (40, None))) == "on the target, not reached"
    assert failures.classify(steps((5, None), (10, 0), (19, None))) == "target never in view"
    # the first box came 2 steps after the target's first view (>= 20 px); NaN where either never comes
    assert failures.first_box_delay(steps((5, None), (25, None), (30, None), (40, 1))) == 2
    assert np.isnan(failures.first_box_delay(steps((5, None), (10, 0))))
    # the report names each class's seeds, so that a lost episode can be replayed
    lines = failures.class_lines({"target missed": [1000031, 1000038], "on a look-alike": [1000004]})
    assert lines[0].endswith(": 3")
    assert "  on a look-alike: 1 (seeds 1000004)" in lines and "  target missed: 2 (seeds 1000031, 1000038)" in lines
    assert "  target never in view: 0" in lines


def test_the_look_over_lead_in_comes_before_the_orbit_and_follows_a_dqn_trained_after_it():
    sweep = Sweep(1, lead_in=LOOK_OVER)
    assert sweep.leading().all()
    refused, free = {"refused": np.array([True])}, {"refused": np.array([False])}
    actions = [int(sweep.act(refused if i == 2 else free)[0]) for i in range(len(LOOK_OVER))]
    assert actions == list(LOOK_OVER)  # a refused lead-in step does not turn the orbit
    assert not sweep.leading().any()
    assert int(sweep.act(free)[0]) == LEFT and int(sweep.act(refused)[0]) == RIGHT
    sweep.reset()
    assert int(sweep.act(free)[0]) == LOOK_OVER[0]
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1))
    trained_after = types.SimpleNamespace(config={"look_over": True})
    assert len(ExplorePolicy(env, then=trained_after).sweep.lead_in) == len(LOOK_OVER)
    assert len(ExplorePolicy(env, then=types.SimpleNamespace(config={})).sweep.lead_in) == 0
    assert len(ExplorePolicy(env, then=trained_after, look_over=False).sweep.lead_in) == 0
    explorer = ExplorePolicy(env, then=trained_after)  # a target in view during the lead-in is not handed over
    seen = np.array([[0.4, 0.4, 0.1, 0.1]], np.float32)
    for _ in LOOK_OVER:
        assert not explorer.update(seen).any()
        explorer.sweep.act(free)
    assert explorer.update(seen).all()
    with pytest.raises(ValueError, match="look_over is the exploration's lead-in"):
        dqn.train(dqn.Args(look_over=True, explore=False), progress=False)


def test_spl_breakdown_puts_each_episode_in_one_class_and_the_losses_add_up(baseline_script):
    spl_breakdown = baseline_script("spl_breakdown")

    def episode(seed, success, see, solved, spl):
        return dict(seed=seed, success=success, steps_to_see=see, steps_to_success=solved, spl=spl)

    fcn = [
        episode(0, 0.0, 35.0, None, 0.0),  # not solved
        episode(1, 1.0, 1.0, 54.0, 18 / 54),  # seen at the search pose, solved 33 steps later than on the ground truth
        episode(2, 1.0, 41.0, 61.0, 26 / 61),  # the far side
        episode(3, 1.0, 1.0, 20.0, 1.0),  # the rest: as fast as the ground truth's
    ]
    ground_truth = [
        episode(0, 0.0, 35.0, None, None),
        *(episode(s, 1.0, 1.0, n, None) for s, n in ((1, 21.0), (2, 60.0), (3, 20.0))),
    ]
    table = spl_breakdown.breakdown(fcn, ground_truth)
    assert {name: count for name, (count, _) in table.items()} == {name: 1 for name in spl_breakdown.CLASSES}
    assert table["a lost glimpse"][1] == pytest.approx((1 - 18 / 54) / 4)
    assert sum(lost for _, lost in table.values()) == pytest.approx(1 - sum(e["spl"] for e in fcn) / 4)
    with pytest.raises(ValueError, match="same seeds"):
        spl_breakdown.breakdown(fcn, ground_truth[::-1])
