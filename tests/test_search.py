"""The memory agent: its recurrent state's resets, GAE, a short training run on worker processes, its checkpoint
and the `memory` policy."""

import dataclasses
import json
import os
import types

import gymnasium as gym
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from conftest import ROOT

import mani_active_vision as mav
from mani_active_vision.agents import search
from mani_active_vision.agents.policies import (
    DOWN,
    FORWARD,
    LEFT,
    RIGHT,
    STAY_INDEX,
    SWEEP_TURN,
    UP,
    ExplorePolicy,
    MemoryPolicy,
    box_array,
    make_policy,
    policy_kwargs,
)
from mani_active_vision.agents.q_network import checkpoint_env_config, load_q_network
from mani_active_vision.agents.recurrent_network import (
    RecurrentActorCritic,
    features,
    input_dim,
    load_agent,
    save_agent,
)
from mani_active_vision.directions import FINE_AREA, FINE_NEAR_CENTRE
from mani_active_vision.envs import (
    DQN_BOX_HOLD_DROP_CENTRED,
    DQN_FCN_THRESHOLDS,
    DQN_FINE_STEP_SIZE,
    FCN_IMAGE_SIZE,
    EnvConfig,
)
from mani_active_vision.evaluation.protocol import evaluate

SHORT = EnvConfig(with_ee_pos=True, max_episode_steps=12)  # short episodes: the same code, less time


def test_the_gru_state_is_zeroed_where_an_episode_starts():
    torch.manual_seed(0)
    agent = RecurrentActorCritic(input_dim(6), 6, hidden_units=16)
    x = torch.randn(7, 2, agent.input_dim)
    starts = torch.zeros(7, 2)
    starts[4, 0] = 1.0  # env 0's second episode starts at step 4
    state = torch.randn(1, 2, 16)  # whatever the state before: it must not reach past the reset
    hidden, _ = agent.memory(x, state, starts)
    alone, _ = agent.memory(x[4:, :1], agent.initial_state(1), torch.zeros(3, 1))
    torch.testing.assert_close(hidden[4:, :1], alone)
    carried, _ = agent.memory(x[4:, 1:], hidden[3:4, 1:], torch.zeros(3, 1))  # a 1-layer GRU: output = state
    torch.testing.assert_close(hidden[4:, 1:], carried)  # env 1 carries its state across the same steps
    assert not torch.allclose(hidden[4:, 1:], agent.memory(x[4:, 1:], agent.initial_state(1), torch.zeros(3, 1))[0])


def test_an_actor_that_sees_the_input_is_saved_and_loaded_as_such(tmp_path):
    torch.manual_seed(0)
    agent = RecurrentActorCritic(input_dim(7), 7, hidden_units=16, actor_sees_input=True)
    x, starts = torch.randn(3, 2, agent.input_dim), torch.zeros(3, 2)
    hidden, _ = agent.memory(x, agent.initial_state(2), starts)
    other = x.clone()
    other[-1] += 1.0  # the same GRU outputs, another input at the last step: only the head reads it
    assert not torch.allclose(agent.policy(hidden, x)[-1], agent.policy(hidden, other)[-1])
    save_agent(str(tmp_path / "agent.pt"), agent, search.Args())
    loaded, config = load_agent(str(tmp_path / "agent.pt"))
    assert config["actor_sees_input"] and loaded.actor_sees_input
    torch.testing.assert_close(
        loaded(x, agent.initial_state(2), starts)[0], agent(x, agent.initial_state(2), starts)[0]
    )


def test_gae_does_not_bootstrap_across_an_episode_end():
    rewards, values = torch.tensor([[1.0], [0.0], [2.0]]), torch.tensor([[0.5], [0.5], [0.5]])
    ended = torch.tensor([[0.0], [1.0], [0.0]])
    advantages = search.gae(rewards, values, ended, torch.tensor([3.0]), gamma=0.9, lam=1.0)
    # step 1 ends its episode: its return is its reward; step 0's is 1 + 0.9 * 0; step 2 bootstraps from 3
    torch.testing.assert_close(advantages[:, 0], torch.tensor([1.0 - 0.5, 0.0 - 0.5, 2.0 + 0.9 * 3.0 - 0.5]))


def test_features_are_the_box_the_camera_position_and_the_last_action():
    box_state = np.array([[0.1, 0.2, 0.3, 0.4, 0.0, 0.5, 0.9]], np.float32)  # camera at azimuth 90°, radius 0.5
    x = features(box_state, np.array([2]), 6)
    np.testing.assert_allclose(x[0, :8], [0.1, 0.2, 0.3, 0.4, 1.0, 0.0, 0.5, 0.9], atol=1e-6)
    assert x[0, 8:].tolist() == [0, 0, 1, 0, 0, 0]
    assert features(box_state, np.array([-1]), 6)[0, 8:].sum() == 0  # an episode's start: no previous action
    with_stats = np.concatenate([box_state, [[0.06, 0.1, -0.05]]], 1).astype(np.float32)  # share, dx, dy
    x = features(with_stats, np.array([2]), 6)
    assert x.shape == (1, input_dim(6, with_mask_stats=True))
    np.testing.assert_allclose(x[0, 8:11], [0.06, 0.1, -0.05], atol=1e-6)
    assert x[0, 11:].tolist() == [0, 0, 1, 0, 0, 0]
    with_presence = np.concatenate([box_state, [[0.7, 0.06, 0.1, -0.05]]], 1).astype(np.float32)  # presence first
    x = features(with_presence, np.array([2]), 6)
    assert x.shape == (1, input_dim(6, with_mask_stats=True, with_presence=True))
    np.testing.assert_allclose(x[0, 8:12], [0.7, 0.06, 0.1, -0.05], atol=1e-6)
    with pytest.raises(ValueError, match="with_ee_pos=True"):
        features(box_state[:, :4], np.array([-1]), 6)


def test_the_policy_resets_its_memory_at_an_episode_start():
    env = mav.make_env(SHORT)
    try:
        torch.manual_seed(0)
        agent = RecurrentActorCritic(input_dim(6), 6, hidden_units=16)
        policy, fresh = MemoryPolicy(env, agent=agent), MemoryPolicy(env, agent=agent)
        obs, info = env.reset(seed=5)
        policy.reset(obs, info)
        for _ in range(4):
            obs, _, _, _, info = env.step(policy.act(obs, info))
        assert policy.state.abs().sum() > 0 and policy.last_action[0] >= 0  # carried across steps
        obs, info = env.reset(seed=6)
        remembered = policy.state.clone()
        fresh.reset(obs, info)
        fresh.act(obs, info)
        policy.reset(obs, info)
        assert policy.state.abs().sum() == 0 and policy.last_action[0] == -1
        policy.act(obs, info)
        torch.testing.assert_close(policy.state, fresh.state)  # as if it had never acted before
        assert not torch.allclose(
            agent(torch.as_tensor(features(box_array(obs), np.array([-1]), 6))[None], remembered, torch.zeros(1, 1))[2],
            fresh.state,
        )  # without the reset its memory would differ
    finally:
        env.close()


def test_a_short_training_run_on_workers_saves_an_agent_that_acts(tmp_path):
    args = search.Args(
        env=SHORT,
        total_steps=48,
        algo="ppo",
        teacher="servo",
        num_steps=12,
        demo_episodes=1,
        demo_epochs=2,
        run_dir=str(tmp_path),
    )
    result = search.train(args, progress=False)  # 2 worker processes: one servo episode each, then one PPO update
    assert len(result["history"]) == 4 and [h["env_step"] for h in result["history"]] == [24, 24, 48, 48]
    saved_history = json.loads((tmp_path / "seed0" / "history.json").read_text())
    assert [h["demo"] for h in saved_history["history"]] == [True, True, False, False] and saved_history["complete"]
    saved = torch.load(result["checkpoint"], weights_only=True)  # weights and plain data only
    assert EnvConfig.from_dict(saved["config"]["env"]) == SHORT == checkpoint_env_config(result["checkpoint"])
    assert not torch.equal(saved["state_dict"]["actor.weight"], torch.zeros(6, 64))
    env = mav.make_env(checkpoint_env_config(result["checkpoint"]))
    try:
        policy = make_policy("memory", env, **policy_kwargs("memory", checkpoint=result["checkpoint"]))
        episode = evaluate(env, policy, [1_000_000], with_reference=False, progress=False)[0]
    finally:
        env.close()
    assert 0 <= episode["final_target_fraction"] <= 1 and policy.last_action[0] in range(6)


DQN_WEIGHTS = os.path.join(ROOT, "agents", "weights", "dqn_hold_demo_wide.pt")


def test_the_explore_dqn_teacher_follows_the_learners_trajectory():
    stand_in = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(6))
    teacher = search.ExploreDQNTeacher(stand_in, DQN_WEIGHTS)
    unseen, start, going = np.zeros((1, 7), np.float32), np.array([True]), np.array([False])
    assert teacher.act(unseen, {}, start)[0] == LEFT  # the sweep's first direction
    teacher.executed(np.array([UP]))
    assert teacher.act(unseen, {"refused": np.array([True])}, going)[0] == LEFT  # not its direction refused
    teacher.executed(np.array([LEFT]))
    assert teacher.act(unseen, {"refused": np.array([True])}, going)[0] == RIGHT  # its own: it turns back
    teacher.executed(np.array([RIGHT]))
    seen = np.array([[0.3, 0.4, 0.1, 0.1, 0.5, 0.0, 0.6]], np.float32)  # the box, then the camera's position
    q_network, config = load_q_network(DQN_WEIGHTS)
    assert config["with_last_action"] and q_network.state_dim == 10

    def greedy(box, last):  # the DQN on the box and a one-hot of its previous direction (none: zeros)
        with torch.no_grad():
            return q_network(torch.tensor([box + [float(a == last) for a in range(6)]])).argmax(-1).item()

    # at the hand-over the DQN has no previous direction, as when it acts itself
    assert teacher.act(seen, {}, going)[0] == greedy([0.3, 0.4, 0.1, 0.1], None)
    teacher.executed(np.array([DOWN]))  # the learner went down: that is the DQN's previous direction now
    assert teacher.act(unseen, {}, going)[0] == greedy([0.0] * 4, DOWN)  # latched: still the DQN, not the sweep
    assert teacher.act(unseen, {}, start)[0] == LEFT  # a new episode: sweeping again
    with_stay = types.SimpleNamespace(unwrapped=stand_in.unwrapped, action_space=gym.spaces.Discrete(7))
    holding = search.ExploreDQNTeacher(with_stay, DQN_WEIGHTS, stays=True)  # a six-direction DQN, env with stay
    holding.act(unseen, {}, start)
    in_success = {"success": np.array([True]), "target_fraction": np.array([0.06]), "target_center_offset": [0.05]}
    assert holding.act(seen, in_success, going)[0] == STAY_INDEX  # privileged: in success
    holding.executed(np.array([STAY_INDEX]))
    assert holding.act(seen, {"success": np.array([False])}, going)[0] == greedy([0.3, 0.4, 0.1, 0.1], None)
    wary = search.ExploreDQNTeacher(with_stay, DQN_WEIGHTS, stays=True, stay_limits=(0.065, 0.105))
    wary.act(unseen, {}, start)
    assert wary.act(seen, in_success, going)[0] == greedy([0.3, 0.4, 0.1, 0.1], None)  # in success, no margin
    well_inside = {**in_success, "target_fraction": np.array([0.07])}
    assert wary.act(seen, well_inside, going)[0] == STAY_INDEX
    assert wary.act(seen, {**well_inside, "target_center_offset": [0.12]}, going)[0] != STAY_INDEX


def test_with_first_turn_the_teachers_sweep_turns_back_after_that_many_net_steps_in_its_direction():
    stand_in = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(6))
    teacher = search.ExploreDQNTeacher(stand_in, DQN_WEIGHTS, first_turn=3)
    unseen, free = np.zeros((1, 7), np.float32), {"refused": np.array([False])}
    actions = [int(teacher.act(unseen, free, np.array([True]))[0])]
    for learner in (LEFT, UP, LEFT, RIGHT, LEFT, LEFT, RIGHT, RIGHT, RIGHT, RIGHT):
        teacher.executed(np.array([learner]))
        actions.append(int(teacher.act(unseen, free, np.array([False]))[0]))
    # a step against its direction takes one back; after three net steps left it turns right, and only once
    assert actions == [LEFT] * 6 + [RIGHT] * 5
    assert teacher.act(unseen, free, np.array([True]))[0] == LEFT  # a new episode sweeps left again
    explorer = ExplorePolicy(stand_in, first_turn=2)  # the same rule as the exploration's own sweep
    explorer.reset(unseen, {})
    assert [int(explorer.act(unseen, free)[0]) for _ in range(5)] == [LEFT, LEFT, RIGHT, RIGHT, RIGHT]
    with pytest.raises(ValueError, match="first_turn=14 must be >= 0, and 0 with look_over"):
        ExplorePolicy(stand_in, first_turn=14, look_over=True)
    with pytest.raises(ValueError, match="first_turn is the exploration's .policy 'explore'., not policy 'servo'"):
        policy_kwargs("servo", first_turn=14)
    assert policy_kwargs("explore", "dqn", "x.pt", first_turn=SWEEP_TURN)["first_turn"] == SWEEP_TURN
    with pytest.raises(ValueError, match="teacher_first_turn=14 must be >= 0, and is the exploration's"):
        search.check(dataclasses.replace(search.Args(), teacher="servo", teacher_first_turn=14))


SHIPPED_DQN = os.path.join(os.path.dirname(DQN_WEIGHTS), "dqn.pt")


def test_the_shipped_dqn_teaches_on_the_box_and_mask_stats_and_stays_by_itself():
    n7 = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=1), action_space=gym.spaces.Discrete(7))
    q_network, config = load_q_network(SHIPPED_DQN)
    assert config["env"]["with_mask_stats"] and config["avoid_refused"] and q_network.num_actions == 7
    with pytest.raises(ValueError, match="with the mask stats"):
        search.ExploreDQNTeacher(n7, SHIPPED_DQN)  # the learner's state must carry what the DQN was trained on
    teacher = search.ExploreDQNTeacher(n7, SHIPPED_DQN, mask_stats_in_obs=True)
    start, going = np.array([True]), np.array([False])

    def learner_state(box, stats):  # the box, the camera's position, the mask's share and centroid offset
        return np.array([box + [0.5, 0.0, 0.6] + stats], np.float32)

    def q_values(box, stats, last):
        one_hot = [float(a == last) for a in range(7)]
        with torch.no_grad():
            return q_network(torch.tensor([box + stats + one_hot]))[0]

    near, near_stats = [0.3, 0.3, 0.4, 0.4], [0.09, 0.0, 0.0]  # big and centred: well inside success
    far, far_stats = [0.4, 0.4, 0.2, 0.2], [0.05, 0.0, 0.0]  # centred, at the edge of success
    assert teacher.act(np.zeros((1, 10), np.float32), {}, start)[0] == LEFT
    teacher.executed(np.array([LEFT]))
    first = teacher.act(learner_state(near, near_stats), {}, going)[0]
    assert first == q_values(near, near_stats, None).argmax().item() == STAY_INDEX  # it stays by itself
    teacher.executed(np.array([FORWARD]))  # the learner went forward instead
    q = q_values(far, far_stats, FORWARD)
    assert teacher.act(learner_state(far, far_stats), {}, going)[0] == q.argmax().item() == FORWARD  # on forward
    teacher.executed(np.array([FORWARD]))  # and the controller refused it
    q[FORWARD] = -torch.inf  # trained with avoid_refused: a refused action is not asked for again at once
    refused = {"refused": np.array([True])}
    assert teacher.act(learner_state(far, far_stats), refused, going)[0] == q.argmax().item() != FORWARD


def test_a_servo_teacher_that_looks_over_restarts_its_lead_in_per_episode_and_reads_the_learners_steps():
    env = types.SimpleNamespace(unwrapped=types.SimpleNamespace(num_envs=2), action_space=gym.spaces.Discrete(7))
    teacher = search.ServoTeacher(env, look_over=True)
    unseen, free = np.zeros((2, 4), np.float32), {"refused": np.zeros(2, bool)}
    lead_in = teacher.servo.sweep.lead_in
    for step in range(3):  # both envs in the lead-in
        starts = np.array([step == 0, step == 0])
        assert teacher.act(unseen, free, starts).tolist() == [lead_in[step]] * 2
        teacher.executed(np.array([LEFT, LEFT]))
    assert teacher.act(unseen, free, np.array([True, False])).tolist() == [lead_in[0], lead_in[3]]  # env 0 restarts
    teacher.executed(np.array([FORWARD, FORWARD]))
    assert teacher.servo.last_action.tolist() == [FORWARD, FORWARD]  # the learner's, not the teacher's


def test_a_ground_truth_box_teacher_sees_the_segmentations_box_and_the_learners_position():
    seen = []
    stub = types.SimpleNamespace(act=lambda obs, info, starts: seen.append(obs) or np.zeros(2, np.int64))
    teacher = search.GroundTruthBoxTeacher(stub)
    learner_obs = torch.tensor([[0.5, 0.5, 0.1, 0.1, 0.3, 0.0, 0.9], [0.0, 0.0, 0.0, 0.0, 0.2, 0.1, 0.8]])
    truth = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.2, 0.3, 0.1, 0.2]])  # the FCN saw a look-alike, then missed
    teacher.act(learner_obs, {"target_bbox": truth}, np.array([False, False]))
    np.testing.assert_allclose(seen[0][:, :4], truth.numpy())
    np.testing.assert_allclose(seen[0][:, 4:], learner_obs[:, 4:].numpy())
    assert learner_obs[0, 0] == 0.5  # the learner's own observation is left as it was


def test_a_teacher_shown_the_ground_truth_in_success_only_holds_on_its_box_and_mask_stats():
    seen = []
    stub = types.SimpleNamespace(act=lambda obs, info, starts: seen.append(obs) or np.zeros(2, np.int64))
    teacher = search.GroundTruthBoxTeacher(stub, in_success_only=True, with_mask_stats=True)
    learner_obs = np.array([[0.4, 0.4, 0.2, 0.2, 0.05, 0.01, 0.0], [0.1, 0.1, 0.1, 0.1, 0.01, -0.3, -0.3]])
    info = {
        "success": np.array([True, False]),
        "target_bbox": np.array([[0.35, 0.3, 0.3, 0.3], [0.5, 0.5, 0.1, 0.1]]),
        "target_fraction": np.array([0.07, 0.01]),
    }
    teacher.act(learner_obs, info, np.array([False, False]))
    np.testing.assert_allclose(seen[0][0], [0.35, 0.3, 0.3, 0.3, 0.07, 0.0, -0.05], atol=1e-6)  # in success
    np.testing.assert_allclose(seen[0][1], learner_obs[1])  # not in success: the learner's own state
    with pytest.raises(ValueError, match="teacher_box='truth' is not one of"):
        search.check(dataclasses.replace(search.Args(), teacher_box="truth"))


def test_dagger_on_workers_fits_the_teachers_labels(tmp_path):
    args = search.Args(
        env=SHORT,
        total_steps=48,
        algo="dagger",
        teacher=DQN_WEIGHTS,
        dagger_beta_steps=24,
        dagger_batch=2,
        run_dir=str(tmp_path),
    )
    result = search.train(args, progress=False)  # 2 worker processes, 2 rounds of 2 episodes
    saved = json.loads((tmp_path / "seed0" / "history.json").read_text())
    assert saved["complete"] and saved["env_steps"] == 48 and saved["losses"]["episodes_kept"] == 4
    assert np.isfinite(saved["losses"]["dagger_loss"])
    torch.manual_seed(0)
    untrained = RecurrentActorCritic(input_dim(6), 6, 64)
    trained = torch.load(result["checkpoint"], weights_only=True)["state_dict"]
    assert not torch.equal(trained["actor.weight"], untrained.actor.weight)
    torch.testing.assert_close(trained["critic.0.weight"], untrained.critic[0].weight)  # DAgger fits no value


def test_in_an_env_with_the_fine_moves_the_learner_and_its_teachers_keep_seven_actions():
    options = {"fine_near_centre": FINE_NEAR_CENTRE, "fine_from_area": FINE_AREA[0]}

    def zone(name):  # as policies read them; as gymnasium's get_wrapper_attr, an AttributeError for other names
        if name not in options:
            raise AttributeError(name)
        return options[name]

    fine_env = types.SimpleNamespace(
        unwrapped=types.SimpleNamespace(num_envs=2), action_space=gym.spaces.Discrete(13), get_wrapper_attr=zone
    )
    action_map = search.learner_actions(fine_env)  # six directions, stay, then the six fine moves (7-12)
    assert len(action_map.to_env) == 7
    near = np.array([[0.4, 0.4, 0.2, 0.2, 0.5, 0.0, 0.6], [0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.6]], np.float32)
    assert action_map(np.array([LEFT, LEFT]), near).tolist() == [7 + LEFT, LEFT]  # half a step near the target
    assert action_map(np.array([STAY_INDEX, UP]), near).tolist() == [STAY_INDEX, UP]
    servo = search.ServoTeacher(fine_env)
    servo.act(near, {}, np.array([True, True]))
    labels = servo.act(near, {}, np.array([False, False]))  # the servo moves fine near the target: its direction
    assert labels.max() < 7 and servo.servo.act(near, {})[0] >= 7
    servo.executed(np.array([RIGHT, RIGHT]))
    assert servo.servo.last_action.tolist() == [7 + RIGHT, RIGHT]  # the step the env took, as the servo reads it
    teacher = search.ExploreDQNTeacher(fine_env, SHIPPED_DQN, mask_stats_in_obs=True)  # seven actions, as trained
    assert teacher.actions == 7
    six = types.SimpleNamespace(
        unwrapped=fine_env.unwrapped, action_space=gym.spaces.Discrete(12), get_wrapper_attr=zone
    )
    assert len(search.learner_actions(six).to_env) == 6


def test_dagger_in_an_env_with_the_fine_moves_learns_seven_actions(tmp_path):
    fine = SHORT.replace(fine_step_size=0.025, stay_action=True, with_mask_stats=True)
    args = search.Args(env=fine, total_steps=24, teacher=SHIPPED_DQN, dagger_batch=2, run_dir=str(tmp_path))
    result = search.train(args, progress=False)
    agent, config = load_agent(result["checkpoint"])
    assert agent.num_actions == 7 and config["env"]["fine_step_size"] == 0.025
    assert len(result["history"]) == 2  # two 12-step episodes, one per worker


def test_the_focal_imitation_loss_weighs_the_steps_the_learner_gets_wrong():
    logits = torch.tensor([[4.0, 0.0, 0.0], [0.0, 4.0, 0.0]])  # sure of action 0, then of action 1
    labels = torch.tensor([0, 0])  # the teacher says 0 twice: right, then wrong
    torch.testing.assert_close(search.imitation_loss(logits, labels), F.cross_entropy(logits, labels))
    terms = F.cross_entropy(logits, labels, reduction="none")
    p = torch.softmax(logits, -1)[:, 0]
    torch.testing.assert_close(search.imitation_loss(logits, labels, 2.0), (terms * (1 - p) ** 2).mean())
    assert (1 - p[0]) ** 2 < 0.01 < 0.9 < (1 - p[1]) ** 2  # the wrong step keeps its weight, the right one loses it


def test_bad_options_are_named_with_the_valid_ones(tmp_path):
    with pytest.raises(ValueError, match="with_ee_pos must be True"):
        search.check(search.Args(env=EnvConfig()))
    with pytest.raises(ValueError, match="shaping='x' is not one of: none, fraction"):
        search.check(dataclasses.replace(search.Args(), shaping="x"))
    with pytest.raises(ValueError, match="num_envs=3 must be a positive multiple of num_minibatches=2"):
        search.check(dataclasses.replace(search.Args(), num_envs=3))
    with pytest.raises(ValueError, match="total_steps=1000 is less than the teacher's episodes and one rollout"):
        search.check(dataclasses.replace(search.Args(), algo="ppo", total_steps=1000))
    with pytest.raises(ValueError, match="total_steps=100 is less than one episode per env"):
        search.check(dataclasses.replace(search.Args(), total_steps=100))
    with pytest.raises(ValueError, match="algo='sac' is not one of: ppo, dagger"):
        search.check(dataclasses.replace(search.Args(), algo="sac"))
    with pytest.raises(ValueError, match="teacher='nope.pt' is neither servo nor a DQN checkpoint"):
        search.check(dataclasses.replace(search.Args(), teacher="nope.pt"))
    with pytest.raises(ValueError, match="dqn.pt' was trained with with_mask_stats: it needs env.with_mask_stats"):
        search.check(dataclasses.replace(search.Args(), teacher=SHIPPED_DQN))
    with pytest.raises(ValueError, match="teacher_looks_over is the servo's: it needs teacher=servo"):
        search.check(dataclasses.replace(search.Args(), teacher_looks_over=True))
    with pytest.raises(ValueError, match="teacher_stays takes `stay`: it needs env.stay_action"):
        search.check(dataclasses.replace(search.Args(), teacher_stays=True))
    with pytest.raises(ValueError, match=r"teacher_stay_margin=1.5 must be in \[0, 1\)"):
        search.check(dataclasses.replace(search.Args(), teacher_stay_margin=1.5))
    with pytest.raises(ValueError, match="teacher_stay_margin needs teacher_stays and a DQN teacher"):
        search.check(dataclasses.replace(search.Args(), teacher_stay_margin=0.3))
    with pytest.raises(ValueError, match=r"dagger_focal_gamma=-1.0 must be >= 0"):
        search.check(dataclasses.replace(search.Args(), dagger_focal_gamma=-1.0))
    with pytest.raises(ValueError, match="needs a checkpoint"):
        policy_kwargs("memory")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        make_policy("memory", None, checkpoint=str(tmp_path / "missing.pt"))
    env = mav.make_env(EnvConfig(max_episode_steps=5))  # the box alone: no camera position
    try:
        with pytest.raises(ValueError, match="with_ee_pos=True"):
            MemoryPolicy(env, agent=RecurrentActorCritic(input_dim(6), 6, 8))
    finally:
        env.close()
    env = mav.make_env(EnvConfig(max_episode_steps=5, with_ee_pos=True, with_mask_stats=True))
    try:
        with pytest.raises(ValueError, match="takes 14 inputs, the env's box state gives 17"):
            MemoryPolicy(env, agent=RecurrentActorCritic(input_dim(6), 6, 8))
        MemoryPolicy(env, agent=RecurrentActorCritic(input_dim(6, with_mask_stats=True), 6, 8))
    finally:
        env.close()


def shipped_memory_agent(name: str) -> tuple[str, dict, EnvConfig, EnvConfig]:
    """A shipped memory agent's path, config, deployed env and training env."""
    path = os.path.join(ROOT, "agents", "weights", name)
    config = torch.load(path, weights_only=True)["config"]
    return path, config, EnvConfig.from_dict(config["env"]), EnvConfig.from_dict(config["trained_env"])


def assert_acts_in_a_short_episode(path: str, deployed: EnvConfig):
    env = mav.make_env(deployed.replace(max_episode_steps=10))
    try:
        policy = make_policy("memory", env, checkpoint=path)
        evaluate(env, policy, [1_000_000], with_reference=False, progress=False)
    finally:
        env.close()
    assert policy.last_action[0] in range(7)


def test_the_shipped_memory_agent_loads_and_acts_as_deployed():
    path, config, deployed, trained = shipped_memory_agent("search.pt")
    assert (deployed.box_source, deployed.object_set, deployed.with_ee_pos) == ("fcn", "unseen", True)
    assert deployed.stay_action and deployed.with_mask_stats and config["teacher"] == "agents/weights/dqn_ensemble.pt"
    assert config["dagger_focal_gamma"] == 2.0 and config["actor_sees_input"]  # scripts/make_search.sh's recipe
    assert config["teacher_first_turn"] == SWEEP_TURN  # its teacher's sweep turns back at the objects' range
    assert trained == EnvConfig(
        with_ee_pos=True, stay_action=True, with_mask_stats=True, fine_step_size=DQN_FINE_STEP_SIZE
    ).on_fcn_box(DQN_FCN_THRESHOLDS)  # it learnt on the box and the moves it acts with, as its teacher is deployed
    assert load_agent(path)[0].num_actions == 7  # the fine moves are its directions near the target
    # deployed as it learnt, on unseen objects, with `stay` only where the mask stats say success (docs/search.md)
    assert deployed == trained.replace(object_set="unseen", stay_needs_success=True)
    assert deployed.image_size == FCN_IMAGE_SIZE
    assert_acts_in_a_short_episode(path, deployed)


def test_the_memory_agent_shipped_for_occluded_scenes_looks_over_and_acts_as_deployed():
    path, config, deployed, trained = shipped_memory_agent("search_occluded.pt")
    assert config["teacher"] == "servo" and config["teacher_looks_over"] and config["teacher_stays"]
    assert trained == EnvConfig(
        with_ee_pos=True, stay_action=True, with_mask_stats=True, occluders=2, image_size=128, fcn_segment_size=128
    )  # on a 128² camera, the FCN segmenting at 128² where deployed
    # scripts/make_search_occluded.sh's, with `stay` only where the mask stats say success and the held box tracking
    # the camera, as the shipped DQNs' (docs/task.md#occluders)
    on_box = trained.replace(object_set="unseen").on_fcn_box().replace(stay_needs_success=True)
    assert deployed == on_box.with_held_box_tracking()
    assert deployed.box_hold_follows_camera and deployed.box_hold_drop_centred == DQN_BOX_HOLD_DROP_CENTRED
    assert_acts_in_a_short_episode(path, deployed)


def test_the_memory_agent_is_pushed_and_asked_to_recover(tmp_path, baseline_script):
    perturb = baseline_script("perturb")
    checkpoint = os.path.join(ROOT, "agents", "weights", "search.pt")
    env = checkpoint_env_config(checkpoint).replace(box_source="ground_truth", box_hold_steps=0, image_size=32)
    with pytest.raises(ValueError, match="policy='dqn' is not one of: explore, memory"):
        perturb.main(perturb.Args(env=env, checkpoint=checkpoint, policy="dqn"))
    args = perturb.Args(
        env=env, checkpoint=checkpoint, policy="memory", episodes=1, push_steps=[2], recover_limit=5,
        json=str(tmp_path / "perturb.json"),
    )  # fmt: skip
    perturb.main(args)
    results = json.loads((tmp_path / "perturb.json").read_text())["results"]
    assert set(results) == {"servo/push2", "memory/push2"}
    trial = results["memory/push2"]["trials"][0]
    assert set(trial) == {"focused", "visible_after_push", "recovered", "steps_to_recover"}
    assert trial["recovered"] <= trial["focused"]  # recovery is asked only of a focused agent
    perturb.main(dataclasses.replace(args, servo=False))
    results = json.loads((tmp_path / "perturb.json").read_text())["results"]
    assert set(results) == {"memory/push2"} and results["memory/push2"]["trials"] == [trial]  # the same trial
    with pytest.raises(ValueError, match="--no-servo needs a --checkpoint"):
        perturb.main(perturb.Args(env=env, servo=False))


def test_teacher_agreement_asks_the_teacher_on_the_agents_own_steps(tmp_path, baseline_script):
    agreement = baseline_script("teacher_agreement")
    shipped = os.path.join(ROOT, "agents", "weights", "search.pt")
    env = checkpoint_env_config(shipped).replace(max_episode_steps=6)
    result = agreement.main(agreement.Args(env=env, checkpoint=shipped, episodes=1))
    assert result["steps"] == 6 and 0 <= result["agree"] <= 1 and 0 <= result["teacher_stays"] <= 6
    # the first steps are the exploration's sweep, which the agent learnt: they agree there
    assert result["agree_where_teacher_moves"] > 0
    ppo = tmp_path / "ppo.pt"
    save_agent(str(ppo), RecurrentActorCritic(input_dim(7, with_mask_stats=True), 7, 8), search.Args(algo="ppo"))
    with pytest.raises(ValueError, match="algo='ppo': it has no teacher to ask"):
        agreement.main(agreement.Args(env=env, checkpoint=str(ppo), episodes=1))


def test_search_seeds_evaluates_every_agent_on_the_training_scenes_occluders(baseline_script):
    search_seeds = baseline_script("search_seeds")
    args = search_seeds.Args(train=search.Args(env=EnvConfig(occluders=2)))
    for box in ("fcn", "ground_truth"):
        config = search_seeds.eval_config(EnvConfig(), args, box)
        assert config.occluders == 2 and config.object_set == args.eval_object_set and config.box_source == box


def test_search_seeds_tracks_the_held_box_on_the_fcns_box_only_and_keeps_those_evaluations_apart(baseline_script):
    search_seeds = baseline_script("search_seeds")
    args = search_seeds.Args(train=search.Args(env=EnvConfig(occluders=2)))
    tracking = dataclasses.replace(args, held_box_tracking=True)
    on_box = search_seeds.eval_config(EnvConfig(), args, "fcn")
    assert not on_box.box_hold_follows_camera and on_box.box_hold_steps > 0
    assert search_seeds.eval_config(EnvConfig(), tracking, "fcn") == on_box.with_held_box_tracking()
    ground_truth = search_seeds.eval_config(EnvConfig(), tracking, "ground_truth")  # nothing held there
    assert ground_truth == search_seeds.eval_config(EnvConfig(), args, "ground_truth")
    assert search_seeds.memory_path(tracking, 0, "fcn").endswith("eval_fcn_tracking_50.json")
    assert search_seeds.memory_path(tracking, 0, "ground_truth") == search_seeds.memory_path(args, 0, "ground_truth")


def test_search_seeds_evaluates_the_teachers_sweep_and_beside_it_the_default_one(baseline_script, monkeypatch):
    search_seeds = baseline_script("search_seeds")
    calls = {}

    def record(args, path, config, name, box, **kwargs):
        calls[os.path.basename(path)] = (name, kwargs)
        return {}

    monkeypatch.setattr(search_seeds, "evaluate_cached", record)
    turning = search_seeds.Args(train=dataclasses.replace(search.Args(), teacher_first_turn=SWEEP_TURN))
    rows = search_seeds.baselines(turning, "ground_truth")
    assert list(rows)[:2] == ["explore → dqn (the teacher)", "explore → dqn, turning at joint 1's limit"]
    teacher = {"then": "dqn", "checkpoint": turning.dqn_checkpoint}
    assert calls["baseline_explore_ground_truth_50.json"] == ("explore", teacher | {"first_turn": SWEEP_TURN})
    assert calls["baseline_explore_at_limit_ground_truth_50.json"] == ("explore", teacher)
    assert search_seeds.sweep_title(turning).endswith(f"first turn after {SWEEP_TURN} steps)")
    calls.clear()
    assert len(search_seeds.baselines(search_seeds.Args(), "ground_truth")) == 3  # one sweep, the default
    assert calls["baseline_explore_ground_truth_50.json"] == ("explore", teacher)


def test_search_seeds_runs_the_spl_reference_on_the_agents_box_with_their_bars(baseline_script, monkeypatch, tmp_path):
    search_seeds = baseline_script("search_seeds")
    made = []
    monkeypatch.setattr(
        search_seeds, "make_env", lambda config: made.append(config) or types.SimpleNamespace(close=int)
    )
    monkeypatch.setattr(search_seeds, "reference_table", lambda env, seeds: {int(s): 20.0 for s in seeds})
    barred = search_seeds.Args(fcn_thresholds=DQN_FCN_THRESHOLDS, out_dir=str(tmp_path), eval_episodes=2)
    assert search_seeds.references(barred, "fcn") == {1_000_000: 20.0, 1_000_001: 20.0}
    assert (made[0].fcn_acquire_threshold, made[0].fcn_track_threshold) == DQN_FCN_THRESHOLDS  # as evaluate.py's
    assert (tmp_path / "reference_fcn_bars0.97_0.9_2.json").exists()  # not the file of a reference without them
    search_seeds.references(dataclasses.replace(barred, fcn_thresholds=(0.0, 0.0)), "fcn")
    assert made[1].fcn_acquire_threshold == EnvConfig().fcn_acquire_threshold
    assert (tmp_path / "reference_fcn_2.json").exists()


def test_search_seeds_takes_a_finished_run_from_before_an_option_as_run_at_its_default(baseline_script, tmp_path):
    search_seeds = baseline_script("search_seeds")
    args = search_seeds.Args(out_dir=str(tmp_path), total_steps=20_000)
    options = dataclasses.replace(args.train, seed=0, total_steps=20_000, run_dir=str(tmp_path), run_name="seed0")
    config = json.loads(json.dumps(dataclasses.asdict(options)))
    del config["teacher_first_turn"]  # a run saved before the option existed
    (tmp_path / "seed0").mkdir()
    (tmp_path / "seed0" / "history.json").write_text(json.dumps({"complete": True, "config": config}))
    search_seeds.train_seed(args, 0)  # finished: nothing to train
    config.update(run_dir="runs/elsewhere", run_name="")  # trained by agents.search --run-dir into this folder
    (tmp_path / "seed0" / "history.json").write_text(json.dumps({"complete": True, "config": config}))
    search_seeds.train_seed(args, 0)  # still this configuration's run
    turning = dataclasses.replace(args, train=dataclasses.replace(args.train, teacher_first_turn=SWEEP_TURN))
    with pytest.raises(ValueError, match="holds a finished run with other options .teacher_first_turn."):
        search_seeds.train_seed(turning, 0)
