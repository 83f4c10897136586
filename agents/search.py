"""The memory agent: a recurrent policy that searches for the target, centres it and holds it, with no
scripted exploration (issue 16), one file in the CleanRL manner. Two learners, chosen by measurement
(docs/search.md): DAgger from the shipped agent (the default) and recurrent PPO (the shape of CleanRL's
`ppo_atari_lstm.py`, with a GRU on the box state instead of an LSTM on pixels).

    python -m mani_active_vision.agents.search --help
    python -m mani_active_vision.agents.search --seed 0                  # DAgger, 20,000 steps, 2 workers, ~3 min
    python -m mani_active_vision.agents.search --algo ppo --teacher servo --total-steps 50000   # PPO
    python baselines/evaluate.py --policy memory --checkpoint runs/search/seed0/agent.pt --env.box-source fcn \
        --env.image-size 128 --env.box-hold-steps 20 --env.object-set unseen --episodes 50   # as deployed

The paper's DQN without its scripted exploration "completely fails" on random placements; its authors name
the next step: memory (a sequence model) so that the agent learns to explore. This is that agent:
- input at every step (`agents.recurrent_network.features`): the target's box (zeros when unseen), the
  camera's commanded position (azimuth as sine and cosine, radius, height: where it has looked; the env is
  made with `with_ee_pos`), with `env.with_mask_stats` the mask's share of the image and its centroid's
  offset (where success begins: the shipped agent's), and a one-hot of its own previous action;
- a GRU (64 units) whose state is zeroed at every episode start, in the rollouts, in the updates (whole
  sequences replayed with the same resets) and in evaluation;
- the teacher (`teacher`): the scripted exploration handing over to a DQN checkpoint (by default the
  six-direction `agents/weights/dqn_hold_demo_wide.pt`, the agent shipped before `hold_stay`; the shipped
  `search.pt` learns from `dqn_ensemble.pt`, five DQN runs acting as one, which stays by itself, measured in
  docs/search.md), or the scripted servo; it runs beside the learner and labels the learner's own states (its
  sweep turns on the learner's refusals, its hand-over latches on the learner's first sighting);
- where the env has the fine moves (`env.fine_step_size`) the learner and its teacher keep seven actions, each
  direction taken as its half step near the target (`learner_actions`), as the agent acts when deployed;
- `algo=dagger` (Ross et al., 2011): the greedy learner acts on `num_envs` `make_vec_env` worker processes,
  the teacher acting instead on a share of the steps that falls from 1 to 0 over `dagger_beta_steps`; every
  labelled episode is kept and the policy is fit to all of them (cross-entropy). The memory learns what the
  teacher keeps in its state: which way it sweeps and whether it has seen the target;
- `algo=ppo`: behaviour cloning of the teacher (`demo_episodes` per env), then PPO (clipped surrogate, GAE,
  entropy bonus; a rollout is `num_steps` steps of every env, each minibatch whole sequences of some envs)
  with `demo_coef` (going linearly to `demo_coef_end`) times the cross-entropy against the teacher's labels;
  the learner's reward is the DQN's `hold` reward (`agents.dqn.LearnerReward`, docs/design.md §9); a
  truncated episode is treated as ended (no bootstrap past the step limit), as CleanRL does.
The episode is the task as it is (100 steps from the `sky` start, no end at success). Training is on the
ground-truth box by default (cheaper); the shipped agent learns on the FCN's box as it is deployed, the
teacher acting on the same box, so that its labels match what the learner sees (scripts/make_search.sh,
docs/search.md). `--track` writes the training scalars to TensorBoard.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import random
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from tqdm import tqdm

from mani_active_vision.agents.dqn import (
    SHAPINGS,
    TRAIN_SEED_STRIDE,
    LearnerReward,
    env_info,
    last_step,
    tensorboard_writer,
)
from mani_active_vision.agents.policies import (
    LEFT,
    RIGHT,
    STAY_INDEX,
    ActionMap,
    ServoPolicy,
    box_array,
    fine_zone,
    in_success_with_margin,
    info_flags,
    margin_limits,
    num_actions,
    one_hot,
    rule_out_refused,
)
from mani_active_vision.agents.q_network import checkpoint_env_config, load_q_network
from mani_active_vision.agents.recurrent_network import RecurrentActorCritic, features, input_dim, save_agent
from mani_active_vision.directions import DIRECTIONS, FINE
from mani_active_vision.envs import EnvConfig
from mani_active_vision.evaluation.rollout import stop_on_ctrl_c
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import Trajectory, episode_metrics
from mani_active_vision.vec_env import make_vec_env


@dataclass
class Args:
    env: EnvConfig = field(default_factory=lambda: EnvConfig(with_ee_pos=True))
    """the env the agent learns in (needs with_ee_pos; stored in the checkpoint, evaluation reads it back)"""
    seed: int = 0
    """seed of the run (torch, numpy, the envs' first episodes)"""
    total_steps: int = 20_000
    """env steps in all (summed over the envs); ppo rounds down to whole rollouts"""
    num_envs: int = 2
    """make_vec_env worker processes that collect at once"""
    num_steps: int = 100
    """steps of each env per rollout (the task's episodes are 100 steps)"""
    num_minibatches: int = 2
    """minibatches per epoch; each holds the whole sequences of num_envs / num_minibatches envs"""
    update_epochs: int = 4
    """passes over each rollout"""
    learning_rate: float = 3e-4
    """Adam learning rate"""
    anneal_lr: bool = True
    """decay the learning rate linearly to 0 over the run"""
    gamma: float = 0.99
    """discount"""
    gae_lambda: float = 0.95
    """λ of generalised advantage estimation"""
    clip_coef: float = 0.2
    """PPO's clipping of the probability ratio"""
    ent_coef: float = 0.001
    """weight of the entropy bonus"""
    vf_coef: float = 0.5
    """weight of the value loss"""
    max_grad_norm: float = 0.5
    """gradient clipping"""
    hidden_units: int = 64
    """units of the encoder and the GRU"""
    actor_sees_input: bool = False
    """the policy is a hidden layer on the GRU's output and the current step's encoding (a linear head on the
    GRU's output otherwise): the teacher's stay, a decision on the current box, need not hang on the memory"""
    shaping: str = "log_fraction_centred"
    """the learner's reward (agents.dqn.LearnerReward): the potential Φ (none, fraction, log_fraction,
    log_fraction_centred)"""
    shaping_scale: float = 5.0
    """Φ is multiplied by this"""
    success_bonus: float = 1.0
    """added at the first success of an episode"""
    hold_reward: float = 0.2
    """added at every later step in success"""
    step_cost: float = 0.02
    """subtracted at every step"""
    refusal_penalty: float = 0.1
    """subtracted at a refused step"""
    stay_penalty: float = 0.0
    """subtracted at a `stay` out of success (env.stay_action)"""
    demo_episodes: int = 30
    """ppo: episodes per env of the teacher whose actions the agent imitates before PPO (behaviour cloning, its
    value fit to their returns; their env steps count in total_steps); 0: PPO from scratch"""
    demo_epochs: int = 300
    """ppo: passes of behaviour cloning over the teacher's episodes"""
    demo_learning_rate: float = 1e-3
    """ppo: Adam learning rate of the behaviour cloning"""
    demo_coef: float = 1.0
    """weight in PPO's loss of the cross-entropy against the teacher's action in the agent's own states
    (DAgger's labels), at the start of PPO; it goes linearly to demo_coef_end over the run (both 0: off)"""
    demo_coef_end: float = 0.0
    """that weight at the end of the run (demo_coef: constant)"""
    algo: str = "dagger"
    """ppo: behaviour cloning, then PPO with the teacher's labels (above); dagger: DAgger alone (the learner
    acts, the teacher labels its states, every labelled episode is kept and the policy is fit to them; the
    demo_* and PPO options are not used)"""
    teacher: str = "agents/weights/dqn_hold_demo_wide.pt"
    """whose actions label the learner's states (and play the cloned episodes): servo (the scripted servo), or
    a DQN checkpoint (the scripted exploration handing over to that DQN, as it is deployed), e.g.
    agents/weights/dqn_hold_demo_wide.pt (six directions, the box alone) or agents/weights/dqn_hold_stay.pt or
    dqn.pt (`stay` and the mask stats: need env.stay_action and env.with_mask_stats)"""
    teacher_looks_over: bool = False
    """with teacher=servo: the servo looks over the occluders (the LOOK_OVER lead-in, then it approaches from
    above: `ServoPolicy(look_over=True)`), for scenes with env.occluders (docs/task.md#occluders)"""
    teacher_first_turn: int = 0
    """with a DQN teacher: its exploration's orbit first turns back after this many orbit steps
    (policies.SWEEP_TURN), as `ExplorePolicy(first_turn=...)`; 0: at joint 1's limit"""
    teacher_stays: bool = False
    """the teacher takes `stay` (the env needs stay_action) while the task reports success: privileged (the
    ground truth's success), a teacher that shows holding"""
    teacher_box: str = "observed"
    """the box the teacher acts on: observed (the learner's, env.box_source) or ground_truth (the
    segmentation's, from the task's info: privileged, so that a learner on the FCN's box is labelled by a
    teacher that sees the target as it is), or ground_truth_in_success (the ground truth's box and mask stats
    on the steps where the task reports success, the learner's elsewhere: a teacher that holds on a steady box)"""
    teacher_stay_margin: float = 0.0
    """with teacher_stays and a DQN teacher: it stays only where success holds with this margin (the target's
    share at least (1 + m) times env.success_fraction, its centre offset at most (1 - m) times
    env.success_center_tol), so that the learner's stay, learnt from the box alone, errs inside success"""
    dagger_beta_steps: int = 10_000
    """dagger: env steps over which the share of steps on which the teacher's action is taken instead of the
    learner's falls linearly from 1 to 0"""
    dagger_updates: int = 8
    """dagger: gradient steps after each round of finished episodes"""
    dagger_batch: int = 32
    """dagger: labelled episodes per gradient step (drawn from all kept so far)"""
    dagger_learning_rate: float = 1e-3
    """dagger: Adam learning rate"""
    dagger_focal_gamma: float = 0.0
    """dagger: each step's cross-entropy weighted by (1 - p)^gamma, p the learner's probability of the teacher's
    action (focal loss, Lin et al. 2017): the few steps it still gets wrong, such as leaving success while the
    teacher stays, weigh more than the many it has learnt; 0: plain cross-entropy"""
    run_dir: str = "runs/search"
    """where the checkpoint and history go (a folder per run is made inside)"""
    run_name: str = ""
    """the run's folder name (default: seed<k>)"""
    track: bool = False
    """also write the training scalars to TensorBoard in the run's folder (the optional extra `track`)"""


ALGOS = ("ppo", "dagger")
TEACHER_BOXES = ("observed", "ground_truth", "ground_truth_in_success")


def check(args: Args):
    """Bad options fail before any worker starts, naming the value and the valid ones."""
    if not args.env.with_ee_pos:
        raise ValueError("the memory agent needs the camera's commanded position: env.with_ee_pos must be True")
    if args.env.box_source not in ("ground_truth", "fcn"):
        raise ValueError(f"env.box_source={args.env.box_source!r} is not one of: ground_truth, fcn")
    if args.demo_episodes and args.env.terminate_on_success:
        raise ValueError(
            "demo_episodes cuts the servo's play into whole episodes of max_episode_steps: it needs "
            "env.terminate_on_success off"
        )
    if args.algo not in ALGOS:
        raise ValueError(f"algo={args.algo!r} is not one of: {', '.join(ALGOS)}")
    if args.algo == "dagger" and args.env.terminate_on_success:
        raise ValueError("algo=dagger fits whole episodes of max_episode_steps: it needs env.terminate_on_success off")
    if args.teacher != "servo" and not os.path.isfile(args.teacher):
        raise ValueError(f"teacher={args.teacher!r} is neither servo nor a DQN checkpoint file")
    if args.teacher != "servo":
        taught_in = checkpoint_env_config(args.teacher)  # the learner's state must carry what the DQN reads
        for option in ("with_mask_stats", "stay_action"):
            if getattr(taught_in, option) and not getattr(args.env, option):
                raise ValueError(f"teacher {args.teacher!r} was trained with {option}: it needs env.{option}")
    if args.teacher_looks_over and args.teacher != "servo":
        raise ValueError(f"teacher_looks_over is the servo's: it needs teacher=servo, not {args.teacher!r}")
    if args.teacher_first_turn < 0 or (args.teacher_first_turn and args.teacher == "servo"):
        raise ValueError(
            f"teacher_first_turn={args.teacher_first_turn} must be >= 0, and is the exploration's: it needs a DQN "
            "teacher, not servo"
        )
    if args.teacher_stays and not args.env.stay_action:
        raise ValueError("teacher_stays takes `stay`: it needs env.stay_action")
    if args.teacher_box not in TEACHER_BOXES:
        raise ValueError(f"teacher_box={args.teacher_box!r} is not one of: {', '.join(TEACHER_BOXES)}")
    if not 0 <= args.teacher_stay_margin < 1:
        raise ValueError(f"teacher_stay_margin={args.teacher_stay_margin} must be in [0, 1)")
    if args.teacher_stay_margin and (not args.teacher_stays or args.teacher == "servo"):
        raise ValueError("teacher_stay_margin needs teacher_stays and a DQN teacher (not servo)")
    if args.dagger_focal_gamma < 0:
        raise ValueError(f"dagger_focal_gamma={args.dagger_focal_gamma} must be >= 0 (0: plain cross-entropy)")
    if args.shaping not in SHAPINGS:
        raise ValueError(f"shaping={args.shaping!r} is not one of: {', '.join(SHAPINGS)}")
    if args.num_envs < 1 or args.num_envs % args.num_minibatches:
        raise ValueError(
            f"num_envs={args.num_envs} must be a positive multiple of num_minibatches={args.num_minibatches}"
        )
    if args.algo == "dagger":
        if args.total_steps < args.num_envs * args.env.max_episode_steps:
            raise ValueError(
                f"total_steps={args.total_steps} is less than one episode per env "
                f"(num_envs * env.max_episode_steps = {args.num_envs * args.env.max_episode_steps})"
            )
        return
    demo_steps = args.demo_episodes * args.env.max_episode_steps * args.num_envs
    if args.total_steps < demo_steps + args.num_envs * args.num_steps:
        raise ValueError(
            f"total_steps={args.total_steps} is less than the teacher's episodes and one rollout "
            f"({demo_steps} + num_envs * num_steps = {args.num_envs * args.num_steps})"
        )


@dataclass
class Rollout:
    """One rollout, (T, N) per env and step: the network's inputs `x`, `starts` (the observation is an
    episode's first: the GRU's state is zeroed before it), the actions taken, their log-probabilities and
    values, the learner's rewards, `ended` (the episode ended with this step's action), the servo's action
    in the same state (`expert`), and the GRU's state before the rollout's first step."""

    x: torch.Tensor
    starts: torch.Tensor
    actions: torch.Tensor
    logprobs: torch.Tensor
    values: torch.Tensor
    rewards: torch.Tensor
    ended: torch.Tensor
    expert: torch.Tensor
    first_state: torch.Tensor | None = None

    @classmethod
    def empty(cls, steps: int, num_envs: int, input_dim: int) -> Rollout:
        zeros = functools.partial(torch.zeros, steps, num_envs)
        long = functools.partial(zeros, dtype=torch.long)
        return cls(zeros(input_dim), zeros(), long(), zeros(), zeros(), zeros(), zeros(), long())


def gae(rewards, values, ended, next_value, gamma: float, lam: float) -> torch.Tensor:
    """Generalised advantages (T, N); `ended[t]` marks an episode that ended with step t's action (its
    successor is the next episode's first state, not to be bootstrapped from)."""
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(rewards.shape[0])):
        following = next_value if t == rewards.shape[0] - 1 else values[t + 1]
        carry = 1.0 - ended[t]
        delta = rewards[t] + gamma * following * carry - values[t]
        last = delta + gamma * lam * carry * last
        advantages[t] = last
    return advantages


TRACKED = ("return", "learner_return", "success", "success_final", "focus_held", "steps_to_see")


def learner_actions(env) -> ActionMap:
    """The learner's actions as the env's: the six directions (and `stay`), each direction taken as its fine move
    while the box is near success where the env has the fine moves (env.fine_step_size), as `MemoryPolicy` acts
    when deployed; so the learner and its teacher keep seven actions and learn the half steps' dynamics."""
    env_count = num_actions(env)
    policy_count = env_count - len(FINE) if env_count > len(DIRECTIONS) + 1 else env_count
    return ActionMap(policy_count, env_count, fine_zone(env))


class Collector:
    """The vector env and what the learner keeps of it between steps: the latest observation and info, each
    env's previous action and whether its next observation is an episode's first, the learner's reward and
    the episode's trajectory; a finished episode's metrics go to `history` (with the env step it ended at).
    `step` takes the learner's actions (`learner_actions`) and gives the env theirs."""

    def __init__(self, env, args: Args, writer=None):
        self.env, self.args, self.writer, self.n = env, args, writer, env.num_envs
        self.action_map = learner_actions(env)
        self.actions = len(self.action_map.to_env)
        self.obs, self.info = env.reset(seed=[args.seed * TRAIN_SEED_STRIDE + i for i in range(self.n)])
        self.learner_rewards = [LearnerReward(args, args.env.success_fraction) for _ in range(self.n)]
        self.trajectories = [Trajectory() for _ in range(self.n)]
        self.learner_return = np.zeros(self.n)
        for i in range(self.n):
            self._start(i)
        self.last_action = np.full(self.n, -1)
        self.starts = torch.ones(self.n)  # the next observation is an episode's first
        self.history, self.global_step = [], 0

    def _start(self, i: int):
        self.learner_return[i] = 0.0
        self.learner_rewards[i].reset(env_info(self.info, i))
        self.trajectories[i].start(env_info(self.info, i))

    def features(self) -> torch.Tensor:
        return torch.as_tensor(features(box_array(self.obs), self.last_action, self.actions))

    def step(self, action: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """Step every env; returns the learner's rewards (N,) and which episodes ended with this step (N,)."""
        self.obs, reward, terminated, truncated, self.info = self.env.step(self.action_map(action, self.obs))
        _, final_info = last_step(self.obs, self.info)  # the finished episodes' last step (same-step reset)
        done = np.asarray(terminated) | np.asarray(truncated)
        self.global_step += self.n
        learned = torch.zeros(self.n)
        for i in range(self.n):
            view = env_info(final_info, i)
            learned[i] = self.learner_rewards[i](reward[i : i + 1], view, stayed=action[i] == STAY_INDEX)
            self.learner_return[i] += float(learned[i])
            self.trajectories[i].append(reward[i : i + 1], view)
            if done[i]:
                entry = {"env_step": self.global_step, "learner_return": self.learner_return[i]}
                self.history.append({**entry, **episode_metrics(self.trajectories[i])})
                if self.writer is not None:
                    for key in TRACKED:
                        if not math.isnan(self.history[-1][key]):
                            self.writer.add_scalar(f"charts/{key}", self.history[-1][key], self.global_step)
                self._start(i)  # info is already the next episode's first
        self.last_action = np.where(done, -1, action)
        self.starts = torch.as_tensor(done, dtype=torch.float32)
        return learned, self.starts.clone()


class ServoTeacher:
    """The scripted servo as the teacher, asked in the learner's own states; its sweep (and, with `look_over`,
    its lead-in) restarts with every episode and turns on refused steps (whoever took them). With `stays` it
    takes `stay` in success; with `look_over` it looks over the occluders (`ServoPolicy(look_over=True)`) and
    its rules against repeating a refused step or turning straight back read the learner's previous action."""

    def __init__(self, env, stays: bool = False, look_over: bool = False):
        self.servo = ServoPolicy(env, hold=stays, look_over=look_over)
        self.action_map, self.obs = learner_actions(env), None  # the servo acts in the env's actions

    def act(self, obs, info, starts: np.ndarray) -> np.ndarray:
        sweep = self.servo.sweep
        sweep.direction[starts], sweep.steps[starts], sweep.turned[starts] = sweep.first, 0, False
        self.servo.last_action[starts] = -1
        self.obs = obs
        return self.action_map.to_policy[self.servo.act(obs, info)]

    def executed(self, action: np.ndarray):
        self.servo.last_action[:] = self.action_map(np.asarray(action), self.obs)


class ExploreDQNTeacher:
    """The shipped agent as the teacher: the scripted exploration (orbit, turning back when its own direction
    is refused) until the target is first seen, then a DQN checkpoint, asked in the learner's own states. It
    follows the learner's trajectory: the hand-over latches on the learner's first sighting and the DQN's
    previous action is the one the learner took, as it would be had the DQN acted. The DQN sees what it was
    trained on: the box (x, y, w, h), the mask stats if its env had them (the last three numbers of the
    learner's state: `mask_stats_in_obs`), a one-hot of its previous action if it used one; a DQN trained with
    `avoid_refused` does not repeat an action the controller has just refused, as `DQNPolicy` does. A DQN
    with `stay` (the shipped `hold_stay` one) stays by itself; with `stays` (the env has `stay`, the DQN may
    not) it also takes `stay` while the task reports success and the target's share is at least
    `stay_limits[0]` and its centre offset at most `stay_limits[1]` (`Args.teacher_stay_margin`); a `stay` is
    no previous direction for a six-direction DQN. With `first_turn` its orbit first turns back once the learner
    has taken that many more steps in its direction than against it (`ExplorePolicy(first_turn=...)` in the
    learner's states)."""

    def __init__(
        self,
        env,
        checkpoint: str,
        stays: bool = False,
        stay_limits: tuple[float, float] = (0.0, 1.0),
        mask_stats_in_obs: bool = False,
        first_turn: int = 0,
    ):
        self.q_network, config = load_q_network(checkpoint)
        self.first_turn = first_turn
        self.n, self.actions, self.stays = env.unwrapped.num_envs, len(learner_actions(env).to_env), stays
        self.stay_limits = stay_limits
        self.with_last_action = bool(config.get("with_last_action", False))
        self.avoid_refused = bool(config.get("avoid_refused", False))
        self.mask_stats = bool(config["env"].get("with_mask_stats", False))
        q_actions = self.q_network.num_actions
        expected = 4 + 3 * self.mask_stats + (q_actions if self.with_last_action else 0)
        if (
            self.q_network.state_dim != expected
            or q_actions not in (self.actions, len(DIRECTIONS))
            or (self.mask_stats and not mask_stats_in_obs)
        ):
            raise ValueError(
                f"teacher {checkpoint!r} takes a state of {self.q_network.state_dim} numbers and {q_actions} "
                f"actions{' (with the mask stats)' if self.mask_stats else ''}; the learner's env gives the box (4)"
                f"{', the mask stats (3)' if mask_stats_in_obs else ''} and {self.actions} actions (the six "
                f"directions{' and stay' if self.actions > len(DIRECTIONS) else ''})"
            )
        self.direction = np.full(self.n, LEFT)
        self.orbit_steps = np.zeros(self.n, dtype=np.int64)  # net steps in its direction before its first turn
        self.turned = np.zeros(self.n, dtype=bool)
        self.handed_over = np.zeros(self.n, dtype=bool)
        self.last_action = np.full(self.n, -1)
        self.executed_action = np.full(self.n, -1)

    def act(self, obs, info, starts: np.ndarray) -> np.ndarray:
        refused = info_flags(info, "refused", self.n) & ~starts
        turn = refused & (self.executed_action == self.direction)
        if self.first_turn:
            turn |= (self.orbit_steps >= self.first_turn) & ~self.turned & ~starts
        self.direction[turn] = np.where(self.direction[turn] == LEFT, RIGHT, LEFT)
        self.turned |= turn
        self.direction[starts], self.handed_over[starts], self.last_action[starts] = LEFT, False, -1
        self.orbit_steps[starts], self.turned[starts] = 0, False
        box_state = box_array(obs)
        self.handed_over |= box_state[:, 2] > 0
        parts = [box_state[:, :4]] + ([box_state[:, -3:]] if self.mask_stats else [])
        if self.with_last_action:
            parts.append(one_hot(self.last_action, self.q_network.num_actions))
        with torch.no_grad():
            q = self.q_network(torch.as_tensor(np.concatenate(parts, 1)))
        if self.avoid_refused:
            q = rule_out_refused(q, refused, self.last_action)
        action = np.where(self.handed_over, q.argmax(-1).numpy(), self.direction)
        if self.stays:
            action[in_success_with_margin(info, self.n, self.stay_limits) & ~starts] = STAY_INDEX
        return action.astype(np.int64)

    def executed(self, action: np.ndarray):
        """The action the learner took: the DQN's previous action from the hand-over on."""
        self.executed_action = np.asarray(action).copy()
        away = np.where(self.direction == LEFT, RIGHT, LEFT)
        self.orbit_steps += (self.executed_action == self.direction).astype(np.int64) - (self.executed_action == away)
        self.last_action = np.where(self.handed_over, self.executed_action, -1)


class GroundTruthBoxTeacher:
    """A teacher shown the ground truth's box (the task's `info["target_bbox"]`, from the segmentation) in place
    of the learner's, the camera's position kept: privileged labels for a learner on the FCN's box.

    With `in_success_only`, only on the steps where the task reports success, and the mask stats too (the
    target's share, `info["target_fraction"]`, and its box centre's offset from the image centre for the
    centroid's): where the target is whole and large the two boxes agree, and the teacher holds on the
    ground truth's steady box (focus held 0.94 against 0.84 on the FCN's flickering one, docs/search.md)."""

    def __init__(self, teacher, in_success_only: bool = False, with_mask_stats: bool = False):
        self.teacher, self.in_success_only, self.with_mask_stats = teacher, in_success_only, with_mask_stats

    def act(self, obs, info, starts: np.ndarray) -> np.ndarray:
        state = box_array(obs).copy()
        rows = info_flags(info, "success", len(state)) if self.in_success_only else np.ones(len(state), bool)
        box = np.asarray(info["target_bbox"], dtype=np.float32).reshape(len(state), 4)
        state[rows, :4] = box[rows]
        if self.in_success_only and self.with_mask_stats:
            share = np.asarray(info["target_fraction"], dtype=np.float32).reshape(len(state))
            centre = box[:, :2] + box[:, 2:] / 2 - 0.5
            state[rows, -3] = share[rows]
            state[rows, -2:] = centre[rows]
        return self.teacher.act(state, info, starts)

    def executed(self, action: np.ndarray):
        self.teacher.executed(action)


def make_teacher(env, args: Args):
    if args.teacher == "servo":
        teacher = ServoTeacher(env, args.teacher_stays, args.teacher_looks_over)
    else:
        limits = margin_limits(args.env.success_fraction, args.env.success_center_tol, args.teacher_stay_margin)
        teacher = ExploreDQNTeacher(
            env, args.teacher, args.teacher_stays, limits, args.env.with_mask_stats, args.teacher_first_turn
        )
    if args.teacher_box == "observed":
        return teacher
    in_success = args.teacher_box == "ground_truth_in_success"
    return GroundTruthBoxTeacher(teacher, in_success, args.env.with_mask_stats)


def dagger(agent: RecurrentActorCritic, collector: Collector, teacher, args: Args, bar, stop_requested) -> dict:
    """DAgger (Ross et al., 2011) with a recurrent learner: the greedy learner acts (the teacher instead on a
    share of the steps that falls linearly from 1 to 0 over `dagger_beta_steps`), the teacher labels every
    state, and each finished episode (its inputs and labels) is kept. After each round of finished episodes
    the policy takes `dagger_updates` Adam steps of cross-entropy on `dagger_batch` kept episodes, replayed
    through the GRU from a zero state. The value head is not trained. Returns the last step's loss."""
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.dagger_learning_rate)
    rng = np.random.default_rng(args.seed)
    n, kept_x, kept_labels = collector.n, [], []
    current = [([], []) for _ in range(n)]
    state, last_loss = agent.initial_state(n), math.nan
    while collector.global_step + n <= args.total_steps:
        if stop_requested():
            raise KeyboardInterrupt(f"stopped by Ctrl-C after {collector.global_step} env steps")
        beta = max(0.0, 1.0 - collector.global_step / args.dagger_beta_steps) if args.dagger_beta_steps else 0.0
        x, starts = collector.features(), collector.starts.clone()
        label = teacher.act(collector.obs, collector.info, starts.numpy().astype(bool))
        with torch.no_grad():
            logits, _, state = agent(x[None], state, starts[None])
        action = np.where(rng.random(n) < beta, label, logits[0].argmax(-1).numpy())
        teacher.executed(action)
        for i in range(n):
            current[i][0].append(x[i])
            current[i][1].append(int(label[i]))
        _, ended = collector.step(action)
        bar.update(n)
        for i in np.flatnonzero(ended.numpy()):
            kept_x.append(torch.stack(current[i][0]))
            kept_labels.append(torch.tensor(current[i][1]))
            current[i] = ([], [])
        if ended.any():
            for _ in range(args.dagger_updates):
                chosen = rng.choice(len(kept_x), size=min(args.dagger_batch, len(kept_x)), replace=False)
                xs = torch.stack([kept_x[k] for k in chosen], 1)  # (T, B, input_dim)
                labels = torch.stack([kept_labels[k] for k in chosen], 1)
                hidden, _ = agent.memory(xs, agent.initial_state(len(chosen)), torch.zeros(xs.shape[:2]))
                logits = agent.policy(hidden, xs).flatten(0, 1)
                loss = imitation_loss(logits, labels.flatten(), args.dagger_focal_gamma)
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
                last_loss = loss.item()
            recent = collector.history[-20:]
            bar.set_postfix(
                beta=f"{beta:.2f}",
                loss=f"{last_loss:.3f}",
                success=f"{np.mean([h['success'] for h in recent]):.2f}",
                at_end=f"{np.mean([h['success_final'] for h in recent]):.2f}",
            )
    return {"dagger_loss": last_loss, "episodes_kept": len(kept_x)}


def imitation_loss(logits: torch.Tensor, labels: torch.Tensor, focal_gamma: float = 0.0) -> torch.Tensor:
    """Mean cross-entropy of logits (M, A) against labels (M,), each term weighted by (1 - p)^focal_gamma."""
    log_p = F.log_softmax(logits, -1).gather(1, labels[:, None])[:, 0]
    return (-log_p * (1 - log_p.exp()).pow(focal_gamma)).mean() if focal_gamma else -log_p.mean()


def imitate_teacher(agent: RecurrentActorCritic, collector: Collector, teacher, args: Args, bar) -> dict:
    """Behaviour cloning before PPO: the teacher (by default the scripted servo: sweep, centre, approach;
    acting on the training box) plays `demo_episodes` episodes per env; the agent's policy is fit to its actions (cross-entropy, through
    the GRU) and its value head, on the GRU's features held fixed, to the learner's discounted returns, over
    whole episodes for `demo_epochs` epochs (Adam at `demo_learning_rate`). Returns the losses of the first
    and the last epoch."""
    steps, n = args.env.max_episode_steps, collector.n
    demo = Rollout.empty(args.demo_episodes * steps, n, agent.input_dim)
    for t in range(args.demo_episodes * steps):
        demo.x[t], demo.starts[t] = collector.features(), collector.starts
        action = teacher.act(collector.obs, collector.info, collector.starts.numpy().astype(bool))
        teacher.executed(action)
        demo.actions[t] = torch.as_tensor(action)
        demo.rewards[t], demo.ended[t] = collector.step(action)
        bar.update(n)
    returns = gae(demo.rewards, torch.zeros_like(demo.rewards), demo.ended, torch.zeros(n), args.gamma, 1.0)

    def by_episode(values: torch.Tensor) -> torch.Tensor:  # (episodes * T, N, ...) -> (T, episodes * N, ...)
        return values.unflatten(0, (args.demo_episodes, steps)).transpose(0, 1).flatten(1, 2)

    x, actions, returns, starts = (
        by_episode(demo.x),
        by_episode(demo.actions),
        by_episode(returns),
        by_episode(demo.starts),
    )
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.demo_learning_rate)
    losses = []
    for _ in range(args.demo_epochs):
        hidden, _ = agent.memory(x, agent.initial_state(x.shape[1]), starts)
        policy_loss = F.cross_entropy(agent.policy(hidden, x).flatten(0, 1), actions.flatten())
        value_loss = 0.5 * (agent.value(hidden) - returns).pow(2).mean()
        optimizer.zero_grad()
        (policy_loss + value_loss).backward()
        nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        optimizer.step()
        losses.append({"demo_policy_loss": policy_loss.item(), "demo_value_loss": value_loss.item()})
    return {"first_epoch": losses[0], "last_epoch": losses[-1]}


def train(args: Args, progress: bool = True) -> dict:
    """Train one agent; returns {"run_dir", "checkpoint", "history" (one dict per finished episode)}."""
    check(args)
    run_dir = os.path.join(args.run_dir, args.run_name or f"seed{args.seed}")
    os.makedirs(run_dir, exist_ok=True)
    writer = tensorboard_writer(run_dir) if args.track else None
    torch.set_num_threads(1)
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    n, steps = args.num_envs, args.num_steps
    env = make_vec_env(args.env, n, backend="cpu")  # worker processes
    actions = len(learner_actions(env).to_env)
    agent = RecurrentActorCritic(
        input_dim(actions, args.env.with_mask_stats, args.env.with_presence),
        actions,
        args.hidden_units,
        args.actor_sees_input,
    )
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    collector = Collector(env, args, writer)
    rollout = Rollout.empty(steps, n, agent.input_dim)
    state = agent.initial_state(n)
    ppo = args.algo == "ppo"
    demo_steps = args.demo_episodes * args.env.max_episode_steps * n if ppo else 0
    updates = (args.total_steps - demo_steps) // (n * steps) if ppo else 0
    planned = demo_steps + updates * n * steps if ppo else args.total_steps // n * n
    teacher = make_teacher(env, args)  # asked what it would do in the agent's own states (DAgger's expert)
    losses, demo_losses, demo_done, start = {}, {}, 0, time.time()
    bar = tqdm(total=planned, desc=f"search {os.path.basename(run_dir)}", disable=not progress)
    try:
        with stop_on_ctrl_c() as stop_requested:
            if not ppo:
                losses = dagger(agent, collector, teacher, args, bar, stop_requested)
            if ppo and args.demo_episodes:
                demo_losses = imitate_teacher(agent, collector, teacher, args, bar)
                demo_done = len(collector.history)
                bar.write(f"behaviour cloning: {demo_losses}")
            for update in range(updates):
                if stop_requested():
                    raise KeyboardInterrupt(
                        f"stopped by Ctrl-C after {update} updates ({collector.global_step} env steps)"
                    )
                if args.anneal_lr:
                    optimizer.param_groups[0]["lr"] = args.learning_rate * (1.0 - update / updates)
                progress_made = update / updates  # the imitation's weight goes linearly to demo_coef_end
                demo_weight = args.demo_coef + (args.demo_coef_end - args.demo_coef) * progress_made
                rollout.first_state = state.clone()
                for t in range(steps):
                    rollout.x[t], rollout.starts[t] = collector.features(), collector.starts
                    expert = teacher.act(collector.obs, collector.info, collector.starts.numpy().astype(bool))
                    rollout.expert[t] = torch.as_tensor(expert)
                    with torch.no_grad():
                        logits, value, state = agent(rollout.x[t : t + 1], state, rollout.starts[t : t + 1])
                    distribution = torch.distributions.Categorical(logits=logits[0])
                    action = distribution.sample()
                    rollout.actions[t], rollout.logprobs[t] = action, distribution.log_prob(action)
                    rollout.values[t] = value[0]
                    teacher.executed(action.numpy())
                    rollout.rewards[t], rollout.ended[t] = collector.step(action.numpy())
                    bar.update(n)
                with torch.no_grad():  # the value of the state after the rollout, to bootstrap from
                    next_value = agent(collector.features()[None], state, collector.starts[None])[1][0]
                losses = ppo_update(agent, optimizer, args, rollout, next_value, demo_weight)
                if writer is not None:
                    for key, value in losses.items():
                        writer.add_scalar(f"losses/{key}", value, collector.global_step)
                recent = collector.history[-20:]
                bar.set_postfix(
                    success=f"{np.mean([h['success'] for h in recent]):.2f}",
                    at_end=f"{np.mean([h['success_final'] for h in recent]):.2f}",
                    ret=f"{np.mean([h['learner_return'] for h in recent]):.1f}",
                )
    finally:
        bar.close()
        env.close()
        if writer is not None:
            writer.close()
        checkpoint = os.path.join(run_dir, "agent.pt")  # also after Ctrl-C: what was learned so far
        save_agent(checkpoint, agent, args)
        save_json(
            {
                "config": dataclasses.asdict(args),
                "seconds": time.time() - start,
                "env_steps": collector.global_step,
                "demo_env_steps": demo_steps,
                "complete": collector.global_step == planned,
                "losses": losses,
                "demo_losses": demo_losses,
                "history": [{**h, "demo": k < demo_done} for k, h in enumerate(collector.history)],
            },
            os.path.join(run_dir, "history.json"),
        )
    return {"run_dir": run_dir, "checkpoint": checkpoint, "history": collector.history}


def ppo_update(
    agent: RecurrentActorCritic,
    optimizer,
    args: Args,
    rollout: Rollout,
    next_value: torch.Tensor,
    demo_weight: float = 0.0,
) -> dict:
    """PPO's epochs over one rollout; each minibatch is the whole sequences of some envs, replayed through the
    GRU from the rollout's first state with the rollout's resets. `demo_weight` times the cross-entropy of
    the policy against the servo's action in the same states (DAgger's expert labels on the agent's own
    rollout) joins the loss, so that the policy keeps close to the servo where the return does not pull it
    away. Returns the last minibatch's losses."""
    advantages = gae(rollout.rewards, rollout.values, rollout.ended, next_value, args.gamma, args.gae_lambda)
    returns = advantages + rollout.values
    n = rollout.x.shape[1]
    per_batch = n // args.num_minibatches
    for _ in range(args.update_epochs):
        order = torch.randperm(n)
        for first in range(0, n, per_batch):
            envs = order[first : first + per_batch]
            logits, new_values, _ = agent(rollout.x[:, envs], rollout.first_state[:, envs], rollout.starts[:, envs])
            distribution = torch.distributions.Categorical(logits=logits)
            new_logprobs = distribution.log_prob(rollout.actions[:, envs])
            ratio = (new_logprobs - rollout.logprobs[:, envs]).exp()
            advantage = advantages[:, envs]
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
            policy_loss = torch.max(
                -advantage * ratio, -advantage * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)
            ).mean()
            value_loss = 0.5 * (new_values - returns[:, envs]).pow(2).mean()
            entropy = distribution.entropy().mean()
            loss = policy_loss - args.ent_coef * entropy + args.vf_coef * value_loss
            demo_loss = F.cross_entropy(logits.flatten(0, 1), rollout.expert[:, envs].flatten())
            loss = loss + demo_weight * demo_loss
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
            optimizer.step()
    return {
        "policy_loss": policy_loss.item(),
        "value_loss": value_loss.item(),
        "entropy": entropy.item(),
        "demo_loss": demo_loss.item(),
    }


if __name__ == "__main__":
    result = train(tyro.cli(Args))
    print(f"checkpoint: {result['checkpoint']}")
