"""The optional fine moves: the six directions again at `fine_step_size`, through the env, the servo and the DQN
(the fine moves near success, `near_target`), the DQN's mirrored transitions and the recording's action names."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task

import mani_active_vision as mav
from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import (
    ActionMap,
    MemoryPolicy,
    ServoPolicy,
    back_when_close,
    env_actions,
    fine_zone,
    looks_in_success,
    make_policy,
    stay_needs_success,
    too_close,
)
from mani_active_vision.agents.q_network import load_q_network
from mani_active_vision.agents.recurrent_network import RecurrentActorCritic, input_dim
from mani_active_vision.box_state import BoxState
from mani_active_vision.directions import FINE, STAY, action_count, action_names, action_names_for
from mani_active_vision.envs import (
    DQN_BACK_WHEN_CLOSE,
    DQN_BOX_HOLD_DROP_CENTRED,
    DQN_EXPLORE_RESUMES_AFTER,
    DQN_FCN_CANDIDATE_THRESHOLD,
    DQN_FCN_THRESHOLDS,
    DQN_FINE_FROM_AREA,
    DQN_FINE_NEAR_CENTRE,
    DQN_FINE_STEP_SIZE,
    FCN_SEGMENT_SIZE,
    EnvConfig,
)
from mani_active_vision.recording.log import action_name

FORWARD = mav.DIRECTIONS.index("forward")
DOWN = mav.DIRECTIONS.index("down")
BACKWARD = mav.DIRECTIONS.index("backward")
STAY_INDEX = action_names(stay_action=True).index(STAY)


def test_the_fine_moves_follow_the_six_and_stay_and_are_shorter():
    assert action_names(fine_actions=True) == (*mav.DIRECTIONS, *FINE)
    assert action_names(True, True) == (*mav.DIRECTIONS, STAY, *FINE)
    assert [len(action_names_for(n)) for n in (6, 7, 12, 13)] == [6, 7, 12, 13]
    with pytest.raises(ValueError, match=r"no action set has 8 actions: valid counts are \[6, 7, 12, 13\]"):
        action_names_for(8)
    env = mav.DiscreteDirections(cached_task(start_pose="search"), stay_action=True, fine_step=0.025)
    assert env.action_space.n == 13 and env.names[7] == "left_fine"
    env.reset(seed=0)
    controller = env.unwrapped.agent.controller
    for name, length in (("forward", 0.05), ("forward_fine", 0.025), ("up_fine", 0.025)):
        before = controller.target_pos.clone()
        env.step(env.names.index(name))
        assert float(torch.linalg.norm(controller.target_pos - before)) == pytest.approx(length, abs=1e-5)
    before = controller.target_pos.clone()
    env.step(env.names.index("left_fine"))
    env.step(env.names.index("right_fine"))
    torch.testing.assert_close(controller.target_pos, before)  # the fine orbit steps reverse exactly
    with pytest.raises(ValueError, match=r"fine_step=0.05 must be in \[0, step_size=0.05\)"):
        mav.DiscreteDirections(cached_task(start_pose="search"), fine_step=0.05)
    with pytest.raises(ValueError, match=r"fine_step_size=0.1 must be in \[0, step_size=0.05\)"):
        EnvConfig(fine_step_size=0.1)


def test_action_counts_of_discrete_spaces_and_a_clear_error_for_others():
    assert action_count(gym.spaces.Discrete(13)) == 13 and action_count(gym.spaces.MultiDiscrete([7, 7])) == 7
    with pytest.raises(TypeError, match="not a discrete action space: wrap the env in DiscreteDirections"):
        action_count(gym.spaces.Box(-1, 1, (3,)))


def test_shipping_keeps_the_fine_moves_their_zone_and_the_segmenting_size_a_dqn_was_trained_with_unless_told(
    baseline_script, tmp_path
):
    ship_dqn = baseline_script("ship_dqn")
    trained = EnvConfig(stay_action=True, fine_step_size=0.025, with_mask_stats=True)
    checkpoint = str(tmp_path / "q.pt")
    torch.save({"state_dict": {}, "config": {"env": dataclasses.asdict(trained)}}, checkpoint)
    kept = ship_dqn.ship(ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "kept.pt")))
    full = ship_dqn.ship(ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "full.pt"), fine_step_size=0.0))
    assert kept.fine_step_size == 0.025 and full.fine_step_size == 0.0 and kept.box_source == "fcn"
    sharp = ship_dqn.ship(ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "sharp.pt"), fcn_segment_size=128))
    assert kept.fcn_segment_size == 0 and sharp == kept.replace(fcn_segment_size=128)
    assert torch.load(tmp_path / "sharp.pt", weights_only=True)["config"]["env"]["fcn_segment_size"] == 128
    zone = ship_dqn.ship(ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "zone.pt"), fine_near_centre=0.2))
    assert kept.fine_near_centre == 0.3 and zone == kept.replace(fine_near_centre=0.2)
    guarded = ship_dqn.ship(
        ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "guard.pt"), stay_needs_success=True)
    )
    assert not kept.stay_needs_success and guarded == kept.replace(stay_needs_success=True)
    tracking = ship_dqn.ship(
        ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "track.pt"), held_box_tracking=True)
    )
    assert not kept.box_hold_follows_camera and tracking == kept.replace(
        box_hold_follows_camera=True, box_hold_drop_centred=DQN_BOX_HOLD_DROP_CENTRED
    )
    as_dqn = ship_dqn.ship(ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "as_dqn.pt"), as_dqn=True))
    acquire, track = DQN_FCN_THRESHOLDS
    assert (
        as_dqn
        == trained.as_dqn_deployed().replace(object_set="unseen")
        == kept.replace(
            fcn_acquire_threshold=acquire,
            fcn_track_threshold=track,
            fcn_segment_size=FCN_SEGMENT_SIZE,
            fine_step_size=DQN_FINE_STEP_SIZE,
            fine_near_centre=DQN_FINE_NEAR_CENTRE,
            fine_from_area=DQN_FINE_FROM_AREA,
            back_when_close=DQN_BACK_WHEN_CLOSE,
            stay_needs_success=True,
            box_hold_follows_camera=True,
            box_hold_drop_centred=DQN_BOX_HOLD_DROP_CENTRED,
            fcn_border_bar_near_box=True,
            explore_resumes_after=DQN_EXPLORE_RESUMES_AFTER,
            fcn_candidate_threshold=DQN_FCN_CANDIDATE_THRESHOLD,
        )
    )
    no_hold = ship_dqn.ship(
        ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "n.pt"), as_dqn=True, box_hold_steps=0)
    )
    assert not no_hold.box_hold_follows_camera and no_hold == as_dqn.replace(
        box_hold_steps=0, box_hold_follows_camera=False, box_hold_drop_centred=0
    )
    bars = ship_dqn.ship(
        ship_dqn.Args(checkpoint=checkpoint, out=str(tmp_path / "b.pt"), as_dqn=True, fcn_track_threshold=0.5)
    )
    assert bars == as_dqn.replace(fcn_track_threshold=0.5)  # what is given overrides


def test_the_servo_serves_with_the_fine_moves_and_sweeps_with_the_full_step():
    env = BoxState(mav.DiscreteDirections(cached_task(start_pose="search"), fine_step=0.025))
    fine_forward, fine_down = (action_names_for(12).index(f"{d}_fine") for d in ("forward", "down"))

    def act(servo, box):
        return int(servo.act(torch.tensor([box]), {"refused": torch.tensor([False])})[0])

    for fine, served in ((True, fine_forward), (False, FORWARD)):
        servo = ServoPolicy(env, fine=fine)
        servo.reset(None, {})
        assert act(servo, [0.4, 0.4, 0.2, 0.2]) == served  # centred, near (4% of the image): forward
        assert act(servo, [0.45, 0.45, 0.1, 0.1]) == FORWARD  # far (1% of the image): the full step
        assert act(servo, [0.1, 0.1, 0.8, 0.8]) == FORWARD  # too close (64% of the image): the full step
        assert act(servo, [0.0, 0.4, 0.2, 0.2]) == mav.DIRECTIONS.index("left")  # off-centre by 0.4: the full step
        assert act(servo, [0, 0, 0, 0]) == mav.DIRECTIONS.index("left")  # unseen: the sweep's full step
        assert act(servo, [0.4, 0.65, 0.2, 0.2]) == (fine_down if fine else DOWN)  # 0.25 below the centre: near


def test_the_policies_take_the_fine_moves_within_the_envs_fine_zone():
    """The zone of the fine moves is the env's (`EnvConfig.fine_near_centre`, `fine_from_area`): a box of 4% of the
    image 0.25 below the centre is near success at the defaults (0.3, 2%), not at a centre of 0.2 nor from 6% of the
    image, for the servo and for a DQN alike."""
    low = torch.tensor([[0.4, 0.65, 0.2, 0.2]])
    names = action_names_for(13)
    for zone, expected in (((0.3, 0.02), names.index("down_fine")), ((0.2, 0.02), DOWN), ((0.3, 0.06), DOWN)):
        directions = mav.DiscreteDirections(
            cached_task(start_pose="search"), True, fine_step=0.025, fine_near_centre=zone[0], fine_from_area=zone[1]
        )
        env = BoxState(directions)
        assert fine_zone(env) == zone
        servo = ServoPolicy(env)
        servo.reset(None, {})
        assert int(servo.act(low, {"refused": torch.tensor([False])})[0]) == expected
        q_network = dqn.QNetwork(4 + 7, num_actions=7)
        with torch.no_grad():
            q_network.network[2].weight.zero_()
            q_network.network[2].bias[:] = torch.tensor([0.0, 0, 0, 0, 0, 1, 0])  # prefers down
        policy = make_policy("dqn", env, q_network=q_network, with_last_action=True)
        policy.reset(low, {})
        assert int(policy.act(low, {})[0]) == expected
    with pytest.raises(ValueError, match=r"fine_near_centre=0.0 must be in \(0, 0.5\]"):
        EnvConfig(fine_near_centre=0.0)
    with pytest.raises(ValueError, match=r"fine_from_area=0.3 must be in \(0, 0.25\): a share of the image"):
        EnvConfig(fine_from_area=0.3)


def test_a_dqn_steps_back_where_the_env_says_the_box_is_too_close():
    """With `back_when_close` (the deployed DQNs' 0.2) a DQN steps backward while its box, seen this step, touches
    the image's border and covers that share of the image or more; elsewhere, on a held box (`info["box_held"]`: it
    would not change as the camera steps back) and at 0 (the default), it takes its own choice."""
    cut_large = torch.tensor([[0.41, 0.12, 0.46, 0.88]])  # a forward push's view: 40% of the image, cut below
    cut_small = torch.tensor([[0.0, 0.4, 0.2, 0.2]])  # cut, 4% of the image
    whole_large = torch.tensor([[0.2, 0.2, 0.6, 0.6]])  # 36%, inside the image
    assert too_close(torch.cat([cut_large, cut_small, whole_large]).numpy(), 0.2).tolist() == [True, False, False]
    assert not too_close(cut_large.numpy(), 0.0).any()
    for back, expected in ((0.0, STAY_INDEX), (DQN_BACK_WHEN_CLOSE, BACKWARD)):
        env = BoxState(mav.DiscreteDirections(cached_task(start_pose="search"), True, back_when_close=back))
        assert back_when_close(env) == back
        q_network = dqn.QNetwork(4, num_actions=7)
        with torch.no_grad():
            q_network.network[2].weight.zero_()
            q_network.network[2].bias[:] = torch.tensor([0.0, 0, 0, 0, 0, 0, 1])  # prefers stay
        policy = make_policy("dqn", env, q_network=q_network)
        policy.reset(cut_large, {})
        assert int(policy.act(cut_large, {})[0]) == expected and int(policy.act(whole_large, {})[0]) == STAY_INDEX
        assert int(policy.act(cut_large, {"box_held": True})[0]) == STAY_INDEX
    with pytest.raises(ValueError, match=r"back_when_close=1.5 must be in \[0, 1\]"):
        EnvConfig(back_when_close=1.5)


def test_a_learned_policy_stays_only_where_the_mask_stats_say_success_where_the_env_says_so():
    """With `stay_needs_success` (the deployed DQNs') a DQN or a memory agent with `stay` takes it only where the box's
    mask stats show a view in success by the task's bars (5% of the image, the centroid within 0.15, the box not
    cut); elsewhere its next choice. Without it (the default) it stays wherever its network says."""
    rows = {  # box (x, y, w, h), then the mask stats (share, dx, dy)
        "in success": [0.4, 0.4, 0.25, 0.25, 0.06, 0.02, -0.03],
        "off centre": [0.1, 0.4, 0.3, 0.3, 0.09, -0.18, 0.1],
        "too small": [0.45, 0.45, 0.15, 0.15, 0.02, 0.0, 0.0],
        "cut": [0.0, 0.3, 0.5, 0.5, 0.2, -0.1, 0.0],
        "unseen": [0.0] * 7,
    }
    states = torch.tensor(list(rows.values()))
    assert looks_in_success(states.numpy(), 0.05, 0.15).tolist() == [True, False, False, False, False]
    for guard in (False, True):
        task = cached_task(start_pose="search")
        env = BoxState(mav.DiscreteDirections(task, True, stay_needs_success=guard), with_mask_stats=True)
        assert stay_needs_success(env) == guard
        q_network = dqn.QNetwork(7, num_actions=7)
        with torch.no_grad():
            q_network.network[2].weight.zero_()
            q_network.network[2].bias[:] = torch.tensor([0.0, 0, 0.5, 0, 0, 0, 1])  # stay, else forward
        policy = make_policy("dqn", env, q_network=q_network)
        policy.reset(states[:1], {})
        actions = [int(policy.act(state[None], {})[0]) for state in states]
        assert actions == [STAY_INDEX] + [FORWARD if guard else STAY_INDEX] * 4
        # the memory agent too: its states are the box, the camera's position, then the mask stats
        env = BoxState(env.env, with_ee_pos=True, with_mask_stats=True)
        agent = RecurrentActorCritic(input_dim(7, with_mask_stats=True), 7, 8)
        with torch.no_grad():
            agent.actor.weight.zero_()
            agent.actor.bias[:] = torch.tensor([0.0, 0, 0.5, 0, 0, 0, 1])
        policy = MemoryPolicy(env, agent=agent)
        policy.reset(None, {})
        with_position = torch.cat([states[:, :4], torch.tensor([[0.3, 0.0, 0.9]] * len(states)), states[:, 4:]], 1)
        actions = [int(policy.act(state[None], {})[0]) for state in with_position]
        assert actions == [STAY_INDEX] + [FORWARD if guard else STAY_INDEX] * 4
    with pytest.raises(ValueError, match="stay_needs_success judges success from the mask stats"):
        make_policy("dqn", BoxState(mav.DiscreteDirections(task, True, stay_needs_success=True)), q_network=q_network)
    with pytest.raises(ValueError, match="stay_needs_success judges success from the mask stats"):
        EnvConfig(stay_action=True, stay_needs_success=True)
    assert EnvConfig(stay_needs_success=True).stay_needs_success  # nothing to guard without stay
    assert not EnvConfig(stay_action=True).as_dqn_deployed().stay_needs_success  # nothing to judge it by
    assert EnvConfig(stay_action=True, with_mask_stats=True).as_dqn_deployed().stay_needs_success


def test_a_short_training_run_with_the_fine_moves_mirrors_them(tmp_path):
    names = action_names_for(13)
    mirrored = [names[a] for a in dqn.mirrored_actions(13)]
    assert mirrored[7:9] == ["right_fine", "left_fine"] and mirrored[9:] == list(FINE[2:]) and mirrored[6] == STAY
    last_left_fine = np.zeros(4 + 13, np.float32)
    last_left_fine[:4], last_left_fine[4 + 7] = (0.1, 0.2, 0.3, 0.4), 1
    np.testing.assert_allclose(dqn.mirror_state(last_left_fine)[[0, 4 + 7, 4 + 8]], [0.6, 0, 1])
    env = EnvConfig(max_episode_steps=30, stay_action=True, fine_step_size=0.025)
    args = dqn.Args(**dqn.SHAPED, env=env, episodes=1, learning_starts=10, demo_episodes=1, run_dir=str(tmp_path))
    q_network, config = load_q_network(dqn.train(args, progress=False)["checkpoint"])
    assert q_network.num_actions == 13 and config["env"]["fine_step_size"] == 0.025
    assert action_name(np.array([7]), names) == "left_fine" and action_name(np.array([6])) == STAY


def test_training_with_the_fine_moves_as_deployed_keeps_the_networks_seven_actions(tmp_path):
    assert ActionMap(7, 13).to_policy.tolist() == [0, 1, 2, 3, 4, 5, 6, 0, 1, 2, 3, 4, 5]
    assert ActionMap(6, 12).to_policy.tolist() == [0, 1, 2, 3, 4, 5] * 2
    assert ActionMap(13, 13).to_policy.tolist() == list(range(13))
    with pytest.raises(ValueError, match="fine_as_deployed .*env.fine_step_size > 0"):  # before any env is made
        dqn.train(dqn.Args(fine_as_deployed=True, run_dir=str(tmp_path)), progress=False)
    env = EnvConfig(max_episode_steps=40, stay_action=True, fine_step_size=0.025)
    args = dqn.Args(
        **dqn.SHAPED,
        env=env,
        episodes=1,
        learning_starts=10,
        demo_episodes=1,
        fine_as_deployed=True,
        run_dir=str(tmp_path),
    )
    result = dqn.train(args, progress=False)
    q_network, config = load_q_network(result["checkpoint"])
    assert q_network.num_actions == 7 and q_network.state_dim == 4 + 7 and config["fine_as_deployed"]
    assert result["history"][0]["success"]  # the servo's demonstration, its fine moves near success among its steps
    assert not result["history"][0]["pushed"]  # no training pushes in this run


def test_a_dqn_trained_on_the_full_step_acts_with_the_fine_moves_where_the_env_has_them():
    assert env_actions(7, 13).tolist() == [7, 8, 9, 10, 11, 12, 6] and env_actions(6, 12).tolist() == list(range(6, 12))
    assert env_actions(13, 13).tolist() == list(range(13)) and env_actions(7, 7).tolist() == list(range(7))
    with pytest.raises(ValueError, match=r"the Q-network has 7 actions, the env takes 12 .*stay_action"):
        env_actions(7, 12)  # stay is not in the env
    with pytest.raises(ValueError, match=r"the Q-network has 13 actions, the env takes 7"):
        env_actions(13, 7)
    env = BoxState(mav.DiscreteDirections(cached_task(start_pose="search"), stay_action=True, fine_step=0.025))
    q_network = dqn.QNetwork(4 + 7, num_actions=7)
    with torch.no_grad():
        q_network.network[2].weight.zero_()
        q_network.network[2].bias[:] = torch.tensor([0.0, 0, 1, 0, 0, 0, 0])  # prefers forward
    policy = make_policy("dqn", env, q_network=q_network, with_last_action=True)
    box = torch.tensor([[0.4, 0.4, 0.2, 0.2]])
    policy.reset(box, {})
    assert int(policy.act(box, {})[0]) == action_names_for(13).index("forward_fine")  # near: 4% of the image
    assert policy.last_action[0] == FORWARD and policy.state(box)[0, 4:].tolist() == [0, 0, 1, 0, 0, 0, 0]
    assert int(policy.act(torch.tensor([[0.45, 0.45, 0.1, 0.1]]), {})[0]) == FORWARD  # far: 1%, the full step
    policy.epsilon = 1.0
    assert {int(policy.act(box, {})[0]) for _ in range(200)} == set(range(6, 13))  # the fine moves and stay


def test_the_memory_agent_takes_the_fine_moves_near_success():
    env = mav.make_env(EnvConfig(max_episode_steps=5, with_ee_pos=True, stay_action=True, fine_step_size=0.025))
    try:
        policy = MemoryPolicy(env, agent=RecurrentActorCritic(input_dim(7), 7, 8))
        policy.reset(None, {})
        near, far = (
            torch.tensor([[0.4, 0.4, 0.2, 0.2, 0.3, 0.0, 0.9]]),
            torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.9]]),
        )
        tables = policy.action_map
        for obs, mapping in ((near, tables.to_env), (far, tables.to_env_full)):
            action = int(policy.act(obs, {})[0])
            assert action == mapping[policy.last_action[0]] and 0 <= policy.last_action[0] < 7
        assert tables.to_env.tolist() == [7, 8, 9, 10, 11, 12, 6] and tables.to_env_full.tolist() == list(range(7))
    finally:
        env.close()


def test_the_demo_evaluates_on_the_fcns_box_as_the_shipped_dqns_are_deployed(baseline_script):
    demo = baseline_script("demo")
    args = demo.Args()
    fcn, ground_truth = demo.eval_env(args, "fcn"), demo.eval_env(args, "ground_truth")
    assert (
        fcn == args.env.replace(object_set="unseen").as_dqn_deployed() and fcn.fine_near_centre == DQN_FINE_NEAR_CENTRE
    )
    assert ground_truth == args.env.replace(object_set="unseen") and ground_truth.fine_step_size == DQN_FINE_STEP_SIZE
    no_fine = demo.eval_env(dataclasses.replace(args, eval_fine_step_size=0.0), "fcn")
    assert no_fine == fcn.replace(fine_step_size=0.0)
