"""DQN on the target's box (the paper's learner), one file in the CleanRL manner.

    python -m mani_active_vision.agents.dqn --help
    python -m mani_active_vision.agents.dqn paper --seed 0        # the paper's configuration
    python -m mani_active_vision.agents.dqn shaped --seed 0       # ... with our learner's reward (below)
    python -m mani_active_vision.agents.dqn hold --seed 0         # ... that also pays for time in success

The paper's configuration is the default (`Args()`, preset `paper`): an MLP with one hidden layer of 20 units, Adam at lr 1e-3, a
replay buffer of 50,000 transitions, 100 episodes, ε decayed linearly 0.1 -> 0.02 over the episodes, the
box (x, y, w, h) as the state and the target's share of the image as the reward. With `--explore` the
paper's scripted exploration orbits until the target is first seen, then the DQN acts for the rest of the
episode; only the DQN's own transitions go into the replay buffer.

The env is `--env.*` (`mani_active_vision.envs.EnvConfig`, stored in the checkpoint): e.g.
`--env.box-source fcn` learns from the FCN's box, `--env.with-ee-pos` adds the camera's commanded position
(the paper's "link state" experiment), `--env.placement fixed` the paper's first experiment.

Deviations from / additions to the paper (it does not state the rest):
- discount, batch size, learning start and update frequency are not given in the paper: ours are below;
- a target network (on by default: the standard DQN of Mnih et al. 2015), double DQN and the Huber loss
  are options; the default loss is the mean squared TD error;
- episodes of 100 steps (the task's limit); the paper's episode length is not given.

The preset `shaped` (`SHAPED`) keeps the paper's network, optimiser, buffer, 100 episodes and ε schedule
but changes what the learner learns from, because with the paper's reward the DQN did not learn to
focus in 100 episodes (0% success, docs/results.md; `LearnerReward`, docs/design.md §9):
- a training episode ends at the first success, which earns a bonus of 1;
- potential-based shaping 5 (γΦ(s') - Φ(s)) replaces the env's reward, with Φ the mean of the log of the
  target's share (over the success share, two decades mapped to [0, 1]) and how centred it is: getting
  closer and centring pay, hovering does not (the optimal policy is unchanged by such shaping);
- a step costs 0.02 and a refused step 0.1 more, so that cycling is never free;
- γ 0.99 (success lies 20-40 steps away) with 5-step returns;
- the DQN's own previous direction (one-hot) joins the box in its state, so that it can tell a step
  forward from a step back in the same box;
- double DQN; every transition also stored mirrored left-right; 2 updates per env step.
The preset `hold` (`HOLD`) is `shaped` without the episode end at success: the bonus of 1 at the first
success, then `hold_reward` 0.2 for every later step in success, so that keeping the target in focus pays
(shaped ends at success, so it never learns to stay).
`demo_episodes` lets the scripted servo act the first training episodes (with env.stay_action it also stays
in success), its transitions stored as the learner's; `demo_margin` adds DQfD's supervised margin loss on them
(`demo_margin_steps`: only on their first steps).
Evaluation is always on the task as it is (no episode end at success, the env's own reward).

`--num-envs N` collects from N `make_vec_env` worker processes, one training episode each per round (the same
episodes and seeds, the same updates per env step; 1, the default, is the env in this process).
`--track` also writes the training scalars to TensorBoard in the run's folder (`tensorboard --logdir runs/dqn`;
TensorBoard is the optional extra `track`); the learning curve is a PNG either way.
`select_every` validates the greedy agent now and then and saves the network that succeeded most, not the last
(off by default; measured in docs/control.md §7). `snapshots` keeps instead the mean Q of the network's last
states (off by default; measured in docs/control.md §9). The shipped agent's preset is `hold_stay_fine`:
`hold_stay_decay` (stay, the mask stats, the learning rate decayed) trained with the fine moves near success, as it
acts when deployed (docs/control.md §12).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import os
import random
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
import tyro
import tyro.extras
from tqdm import tqdm

from mani_active_vision.agents.policies import (
    STAY_INDEX,
    ActionMap,
    DQNPolicy,
    ExplorePolicy,
    ServoPolicy,
    box_array,
    in_success_with_margin,
    margin_limits,
    num_actions,
)
from mani_active_vision.agents.q_network import QNetwork, ensemble_of, save_q_network
from mani_active_vision.directions import DIRECTIONS, FINE, action_names_for
from mani_active_vision.envs import DQN_FINE_STEP_SIZE, EnvConfig, make_env
from mani_active_vision.evaluation.protocol import evaluate
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import Trajectory, episode_metrics, first_env
from mani_active_vision.vec_env import make_vec_env

TRAIN_SEED_STRIDE = 10_000
"""Training episode k of run seed s resets the env with seed s * TRAIN_SEED_STRIDE + k (evaluation uses
seeds from 1,000,000 up: never a training scene)."""

VALIDATION_OFFSET = 5_000
"""Validation episode k of run seed s (`Args.select_every`) resets with seed s * TRAIN_SEED_STRIDE +
VALIDATION_OFFSET + k: a scene of the run's own training range that its training episodes never reach."""


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env the DQN learns in (stored in the checkpoint; evaluation reads it back)"""
    seed: int = 0
    """seed of the run (torch, numpy, the env's episodes)"""
    episodes: int = 100
    """training episodes (paper: 100)"""
    learning_rate: float = 1e-3
    """Adam learning rate (paper: 1e-3)"""
    end_learning_rate: float = 0.0
    """0: the learning rate stays `learning_rate`; else it goes linearly from `learning_rate` at the first
    episode to this at the last, like ε, so that the last episodes move the network less"""
    buffer_size: int = 50_000
    """replay buffer capacity in transitions (paper: 50,000)"""
    hidden_units: int = 20
    """units of the one hidden layer (paper: 20)"""
    start_epsilon: float = 0.1
    """ε-greedy ε at the first episode (paper: 0.1)"""
    end_epsilon: float = 0.02
    """ε at the last episode, linear in between (paper: 0.02)"""
    gamma: float = 0.9
    """discount (not in the paper)"""
    batch_size: int = 32
    """minibatch size (not in the paper)"""
    learning_starts: int = 100
    """transitions in the buffer before updates start (not in the paper)"""
    train_frequency: int = 1
    """env steps per gradient update (not in the paper)"""
    target_network: bool = True
    """bootstrap from a periodically copied target network (not in the paper)"""
    target_update_steps: int = 250
    """env steps between target-network copies"""
    double_dqn: bool = False
    """double DQN: the online network picks the next action, the target network values it"""
    huber: bool = False
    """Huber (smooth L1) TD loss instead of the squared error"""
    explore: bool = True
    """the paper's scripted exploration until the target is first seen, then the DQN"""
    look_over: bool = False
    """the exploration (and the servo's demonstrations) first look over the occluders (`policies.LOOK_OVER`);
    kept in the checkpoint, so the agent is explored for the same way when it acts (docs/task.md#occluders)"""
    end_at_success: bool = False
    """end a training episode at the first success, a terminal state for the learner (not in the paper;
    evaluation runs the env as it is)"""
    success_bonus: float = 0.0
    """added to the reward of the step that first reaches success in an episode (not in the paper)"""
    demo_episodes: int = 0
    """the first this many of the training episodes are acted by the scripted servo (after the exploration's
    hand-over, where the DQN would act), its transitions stored as the learner's: no seed starts without
    having seen success (demonstrations in the replay buffer, as in DQfD, without its supervised loss; not in
    the paper). With env.stay_action the servo also takes `stay` while in success (`ServoPolicy(hold=True)`,
    privileged), so that the demonstrations show holding"""
    demo_margin: float = 0.0
    """DQfD's large-margin loss on the demonstrations (Hester et al. 2018; they use 0.8): the servo's action
    must be valued this much above every other, a supervised term added to the TD loss (0: off)"""
    demo_margin_steps: int = 0
    """with demo_margin: the margin only on a demonstration's first this many steps after the exploration's hand-over
    (the servo's centring and first approach, where the learner was slowest; its holding and late corrections are
    then learnt from the TD loss alone; docs/control.md §33). 0: on all of its steps"""
    hold_reward: float = 0.0
    """added to the reward of every later step in success: time in success pays, so that a learner whose
    episodes go on past success learns to keep it (not in the paper; needs end_at_success off)"""
    refusal_penalty: float = 0.0
    """subtracted from the reward of a refused step: the arm did not move (not in the paper)"""
    stay_penalty: float = 0.0
    """subtracted from the reward of a `stay` (env.stay_action) out of success: standing still pays only in
    focus, so that a learner does not settle where it is (not in the paper)"""
    hold_margin: float = 0.0
    """time in success pays (hold_reward) only where success holds with this margin: the target's share at least
    (1 + m) times the success share and its centre offset at most (1 - m) times the tolerance; a stay outside that
    costs stay_penalty, and the servo's demonstrations stay only there. A learner that tells success's edge only
    roughly then stays inside it rather than just outside (docs/control.md §7; not in the paper; 0: off)"""
    step_cost: float = 0.0
    """subtracted from the reward of every step: cycling costs, reaching success sooner pays (not in the paper)"""
    shaping: str = "none"
    """none: learn from the env's reward (the paper); fraction, log_fraction or log_fraction_centred: learn
    from γΦ(s') - Φ(s) instead (see `potential`): progress is rewarded, hovering is not (not in the paper)"""
    shaping_scale: float = 1.0
    """Φ is multiplied by this (a larger scale: a stronger signal early on; the optimal policy is the same)"""
    with_last_action: bool = False
    """append a one-hot of the DQN's own previous direction to the state, so that it can tell a step
    forward from a step back in the same box (not in the paper)"""
    mirror_augment: bool = False
    """also store each transition mirrored left-right (box flipped, left and right swapped): the task is
    nearly symmetric, so this doubles the experience (not in the paper; box-only state)"""
    avoid_refused: bool = False
    """the trained agent does not repeat at once an action the controller has just refused (its state is
    unchanged, so a memoryless greedy policy would repeat it to the episode's end): kept in the checkpoint for
    evaluation and deployment; the ε-greedy learner in training acts without it (with it, seeds did worse;
    docs/control.md §7; not in the paper)"""
    select_every: int = 0
    """0: keep the network as training ends. N > 0: every N training episodes from `select_from` on, run the
    greedy agent as it acts after training (explore, then the DQN) on `select_episodes` validation scenes, and keep
    the network that succeeds most (the later on a tie). Validation scenes: the training env and objects, seeds of
    this run's training range that training never reaches (VALIDATION_OFFSET); no learning (not in the paper)"""
    select_from: int = 50
    """the first training episode count at which the network is validated (with select_every)"""
    select_episodes: int = 10
    """validation episodes per check (with select_every)"""
    n_step: int = 1
    """n-step returns: bootstrap after n of the learner's steps (not in the paper)"""
    updates_per_step: int = 1
    """gradient updates per env step (not in the paper)"""
    priority_exponent: float = 0.0
    """prioritised replay (Schaul et al. 2016, proportional): a transition is sampled with probability ∝ (|its last TD
    error| + PRIORITY_FLOOR)^α, this α (a new one at the largest priority so far), and its loss weighted by
    importance sampling, (N P)^-β scaled to at most 1; 0: uniform sampling (not in the paper; one network only)"""
    priority_correction: float = 0.4
    """the importance-sampling exponent β at the first episode, linear to 1 at the last (with priority_exponent)"""
    box_dropout: float = 0.0
    """in training, each step's box is replaced by "not seen" (zeros) with this probability, for the actor and
    the learner alike: the FCN's box misses about a third of the target's views (docs/vision.md), which a
    learner on the ground-truth box never meets (not in the paper; 0: off)"""
    ensemble: int = 1
    """Q-networks trained side by side on the same replay buffer, each from its own initialisation and against
    its own target network; the agent acts on their mean Q (`QNetwork(ensemble=K)`; measured in docs/control.md
    §8, not adopted; not in the paper; 1: one network)"""
    ensemble_batches: bool = False
    """with ensemble, each member learns from its own sampled batch (the same one for all: off), so that the members'
    errors are less alike (as Bootstrapped DQN's data masks do; not in the paper)"""
    push_probability: float = 0.0
    """in training, once a learner's episode first reaches success, with this probability `push_steps` forced steps
    of one random direction follow (the learner is not asked; the steps are stored as its experience), then it acts
    again: it meets the states a perturbation leaves, as `baselines/perturb.py` makes them (measured in
    docs/control.md §8, not adopted; not in the paper; 0: off)"""
    push_steps: int = 6
    """forced steps of a training push (with push_probability)"""
    snapshots: int = 1
    """1: the agent is the network as training ends. K > 1: the agent acts on the mean Q of the network as it was
    at the last K of every `snapshot_every` training episodes, the last one included (kept as `QNetwork(ensemble=K)`):
    one run's late swings averaged out, with no more training (training itself is unchanged; measured in
    docs/control.md §9, not adopted; not in the paper)"""
    snapshot_every: int = 10
    """training episodes between the snapshots averaged (with snapshots)"""
    fine_as_deployed: bool = False
    """with env.fine_step_size: the network keeps the six directions (and `stay`) and, as it is deployed, takes each
    direction's fine move while the box is near success (`policies.ActionMap`), so that it learns the moves it will
    make; the stored actions are the network's own. Off: the network learns all of the env's actions, the fine moves
    among them (docs/control.md §11, §12; not in the paper)"""
    run_dir: str = "runs/dqn"
    """where the checkpoint and history go (a folder per run is made inside)"""
    run_name: str = ""
    """the run's folder name (default: made from the options and the seed)"""
    num_envs: int = 1
    """envs that collect at once, each a `make_vec_env` worker process playing one training episode per round
    (1: the env in this process); the episodes, their seeds and the updates per env step do not change"""
    track: bool = False
    """also write the training scalars (return, success, focus, TD loss, ε, ...) to TensorBoard in the run's
    folder (CleanRL's --track; TensorBoard is an optional extra: pip install -e '.[track]')"""


def linear_schedule(start: float, end: float, duration: int, t: int) -> float:
    """`start` at t = 0, `end` from t = duration on, linear in between."""
    if duration <= 0:
        return end
    return start + (end - start) * min(t, duration) / duration


PRIORITY_FLOOR = 0.01
"""Added to a transition's |TD error| for its priority (`Args.priority_exponent`): none falls out of sampling."""


class ReplayBuffer:
    """A ring buffer of (state, action, reward, next_state, terminated, steps, demo) transitions; `steps` is
    how many env steps the reward sums (1, or up to n for n-step returns), `demo` marks the servo's that DQfD's
    margin applies to (`margin_applies`). Each also has a priority for prioritised sampling (`sample`'s
    `exponent`; `set_priorities`)."""

    def __init__(self, capacity: int, state_dim: int):
        self.states = np.zeros((capacity, state_dim), np.float32)
        self.next_states = np.zeros((capacity, state_dim), np.float32)
        self.actions = np.zeros(capacity, np.int64)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.float32)
        self.steps = np.ones(capacity, np.float32)
        self.demo = np.zeros(capacity, bool)
        self.priorities = np.zeros(capacity)
        self.max_priority = 1.0  # a new transition's: it is sampled soon, then gets its own
        self.capacity, self.size, self._next = capacity, 0, 0

    def add(self, state, action, reward, next_state, terminated, steps=1, demo=False):
        i = self._next
        self.states[i], self.actions[i], self.rewards[i] = state, action, reward
        self.next_states[i], self.terminated[i], self.steps[i] = next_state, terminated, steps
        self.demo[i], self.priorities[i] = demo, self.max_priority
        self._next = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(
        self, batch_size: int, rng: np.random.Generator, exponent: float = 0.0, correction: float = 1.0
    ) -> dict[str, torch.Tensor]:
        """A batch drawn uniformly; with `exponent` α > 0 in proportion to priority^α, with the transitions'
        "indices" and importance-sampling "weights" (N P)^-β (β = `correction`), divided by the largest any
        transition in the buffer could get."""
        if not exponent:
            idx = rng.integers(0, self.size, size=batch_size)
        else:
            probability = self.priorities[: self.size] ** exponent
            probability /= probability.sum()
            idx = rng.choice(self.size, size=batch_size, p=probability)
            weights = (self.size * probability[idx]) ** -correction / (self.size * probability.min()) ** -correction
        keys = ("states", "actions", "rewards", "next_states", "terminated", "steps", "demo")
        batch = {k: torch.as_tensor(getattr(self, k)[idx]) for k in keys}
        if exponent:
            batch.update(indices=torch.as_tensor(idx), weights=torch.as_tensor(weights, dtype=torch.float32))
        return batch

    def set_priorities(self, indices: torch.Tensor, errors: torch.Tensor) -> None:
        """The sampled transitions' new priorities: their |TD errors| + PRIORITY_FLOOR."""
        priorities = errors.abs().double().numpy() + PRIORITY_FLOOR
        self.priorities[indices.numpy()] = priorities
        self.max_priority = max(self.max_priority, float(priorities.max()))


class NStepWindow:
    """The learner's last n steps of an episode, turned into n-step transitions (s_t, a_t, Σ_k γ^k r_t+k,
    s_t+n, terminated, n); at the episode's end the shorter tails are flushed. n = 1: plain transitions."""

    def __init__(self, n: int, gamma: float):
        self.n, self.gamma, self.pending = n, gamma, []

    def push(self, state, action, reward, next_state, terminated: bool, episode_end: bool) -> list[tuple]:
        self.pending.append((state, action, reward))
        out = []
        while self.pending and (len(self.pending) == self.n or episode_end):
            discounted = sum(self.gamma**k * r for k, (_, _, r) in enumerate(self.pending))
            first_state, first_action, _ = self.pending.pop(0)
            out.append((first_state, first_action, discounted, next_state, terminated, len(self.pending) + 1))
        return out


def td_loss(
    q_network: QNetwork,
    target_network: QNetwork,
    batch: dict | list[dict],
    gamma: float,
    double_dqn: bool = False,
    huber: bool = False,
    with_errors: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """The TD loss of a batch: Q(s, a) against r + γ^steps (1 - terminated) max_a' Q_target(s', a')
    (`steps` = 1 where the batch does not say), each transition's term weighted where the batch has "weights"
    (prioritised replay). An ensemble's members each learn against their own target member (and, with double
    DQN, their own argmax), on the one batch or on a list of one batch per member; the loss is the mean over
    members. `with_errors`: (loss, the first member's TD errors Q(s, a) - target, detached)."""
    batches = batch if isinstance(batch, list) else [batch] * q_network.ensemble
    results = [
        _member_td_loss(q_network.member(k), target_network.member(k), b, gamma, double_dqn, huber)
        for k, b in enumerate(batches)
    ]
    loss = torch.stack([loss for loss, _ in results]).mean()
    return (loss, results[0][1]) if with_errors else loss


def _member_td_loss(q_network, target_network, batch: dict, gamma: float, double_dqn: bool, huber: bool):
    with torch.no_grad():
        next_q = target_network(batch["next_states"])
        if double_dqn:
            next_action = q_network(batch["next_states"]).argmax(-1, keepdim=True)
            next_value = next_q.gather(1, next_action).squeeze(1)
        else:
            next_value = next_q.max(-1).values
        discount = gamma ** batch["steps"] if "steps" in batch else gamma
        td_target = batch["rewards"] + discount * (1.0 - batch["terminated"]) * next_value
    q = q_network(batch["states"]).gather(1, batch["actions"][:, None]).squeeze(1)
    errors = (q - td_target).detach()
    if "weights" in batch:
        terms = F.smooth_l1_loss(q, td_target, reduction="none") if huber else (q - td_target) ** 2
        return (batch["weights"] * terms).mean(), errors
    return (F.smooth_l1_loss(q, td_target) if huber else F.mse_loss(q, td_target)), errors


def margin_loss(q_network: QNetwork, batch: dict, margin: float) -> torch.Tensor:
    """DQfD's large-margin loss over the batch's demonstrations: max_a [Q(s, a) + margin (a ≠ a_E)] - Q(s, a_E),
    with a_E the demonstrator's action; zero for a batch without demonstrations."""
    demo = batch["demo"]
    if not demo.any():
        return torch.zeros(())
    q = q_network(batch["states"][demo])
    expert = batch["actions"][demo]
    penalty = margin * (1.0 - F.one_hot(expert, q.shape[-1]).float())
    return ((q + penalty).max(-1).values - q.gather(1, expert[:, None]).squeeze(1)).mean()


def margin_applies(args: Args, demo: bool, learner_step: int, steps: int) -> bool:
    """Whether DQfD's margin applies to a transition of `steps` env steps that an NStepWindow gave out at the learner's
    step `learner_step` of its episode (0: the exploration's hand-over): a demonstration's, and with
    demo_margin_steps only one that starts within its first steps."""
    first_step = learner_step - steps + 1
    return bool(demo) and (args.demo_margin_steps == 0 or first_step < args.demo_margin_steps)


@functools.cache
def mirrored_actions(count: int) -> np.ndarray:
    """For an env with `count` actions (`action_names_for`), the action that mirrors each action left-right:
    left <-> right (and their fine moves), the others (stay too) unchanged."""
    names = action_names_for(count)
    swap = {"left": "right", "right": "left", "left_fine": "right_fine", "right_fine": "left_fine"}
    table = np.array([names.index(swap.get(name, name)) for name in names])
    table.flags.writeable = False  # one table per count, shared (cached): it is read per stored transition
    return table


def mirror_state(
    state: np.ndarray, mask_stats: bool = False, ee_pos: bool = False, presence: bool = False
) -> np.ndarray:
    """The state of the left-right mirrored situation: the box (x, y, w, h) of the mirrored image (zeros,
    the unseen state, stay zeros); with `ee_pos` the camera's commanded position unchanged (the camera looks
    outward from the base's vertical axis, so the mirror through that axis and the camera leaves it in place);
    with `presence` the presence score unchanged; with `mask_stats` the mask's share and centroid offset
    (share, -dx, dy); and, if present, the last action's one-hot (as long as the action set: 6, 7, 12 or 13) with
    left and right swapped. The layout is `BoxState`'s: box, [position], [presence], [mask stats], [last action]."""
    x, y, w, h = state[:4]
    box = np.array([1.0 - x - w if w > 0 else 0.0, y, w, h], np.float32)
    unchanged = state[4 : 4 + 3 * ee_pos + presence]  # the camera's position and the presence score
    start = 4 + len(unchanged)
    stats = state[start : start + 3] * np.array([1.0, -1.0, 1.0], np.float32) if mask_stats else state[4:4]
    rest = state[start + len(stats) :]  # the last action's one-hot, if any
    last_action = rest[mirrored_actions(len(rest))] if len(rest) else rest
    return np.concatenate([box, unchanged, stats, last_action]).astype(np.float32)


SHAPINGS = ("none", "fraction", "log_fraction", "log_fraction_centred")


def potential(info, success_fraction: float, shaping: str) -> float:
    """Φ of the state an `info` describes: the target's fraction of the image over the success fraction,
    capped at 1 ("fraction"), or its logarithm mapped from [1/100, 1] to [0, 1] ("log_fraction"), or the
    mean of that and how centred the target is (1 at the centre, 0 at half the image width away or when
    unseen: "log_fraction_centred"); 0 for "none"."""
    ratio = min(first_env(info, "target_fraction") / success_fraction, 1.0)
    if shaping in ("none", "fraction"):
        return ratio if shaping == "fraction" else 0.0
    log_fraction = max(1.0 + math.log10(ratio) / 2.0, 0.0) if ratio > 0 else 0.0
    if shaping == "log_fraction":
        return log_fraction
    centred = max(1.0 - first_env(info, "target_center_offset") / 0.5, 0.0)  # the offset is inf when unseen
    return 0.5 * (log_fraction + centred)


class LearnerReward:
    """What the learner learns from at each step (docs/design.md §9): the env's reward, or with `shaping`
    the potential difference γΦ(s') - Φ(s) instead; plus the success bonus, then the hold reward in success
    (with `hold_limits`, only well inside it: `policies.margin_limits`), less the refusal and stay penalties and
    the step cost. Call `reset(info)` at an episode's start and the object at every step (also the
    script's steps, so that Φ(s) is always the previous step's)."""

    def __init__(self, args: Args, success_fraction: float, hold_limits: tuple[float, float] = (0.0, math.inf)):
        self.args, self.success_fraction, self.hold_limits = args, success_fraction, hold_limits
        self.previous = 0.0

    def _potential(self, info) -> float:
        return self.args.shaping_scale * potential(info, self.success_fraction, self.args.shaping)

    def reset(self, info):
        self.previous = self._potential(info)
        self.reached = False  # success reached this episode

    def __call__(self, env_reward, info, stayed: bool = False) -> float:
        args, current = self.args, self._potential(info)
        reward = args.gamma * current - self.previous if args.shaping != "none" else float(env_reward[0])
        self.previous = current
        success = bool(first_env(info, "success"))
        held = bool(in_success_with_margin(info, 1, self.hold_limits)[0])  # success, with hold_limits' margin
        if success and not self.reached:  # the bonus once, at the first success
            reward += args.success_bonus
            self.reached = True
        elif held:  # time in success after it (also regained) pays
            reward += args.hold_reward
        idle = args.refusal_penalty * first_env(info, "refused") + args.stay_penalty * (stayed and not held)
        return reward - idle - args.step_cost


class DemoOrLearner:
    """Per env, the scripted servo (`demo`: a demonstration episode) or the learner acts; each is asked only
    when some env needs it, so that the learner's ε draws are the same as when it acts alone."""

    def __init__(self, servo: ServoPolicy, learner: DQNPolicy):
        self.servo, self.learner = servo, learner
        self.demo = np.zeros(learner.num_envs, bool)

    def reset(self, obs, info):
        self.servo.reset(obs, info)
        self.learner.reset(obs, info)

    def act(self, obs, info) -> np.ndarray:
        if self.demo.all():
            return self.servo.act(obs, info)
        if not self.demo.any():
            return self.learner.act(obs, info)
        return np.where(self.demo, self.servo.act(obs, info), self.learner.act(obs, info))


INFO_KEYS = ("target_visible", "success", "target_fraction", "target_center_offset", "refused")
"""What the learner reads of an env's info."""


def env_info(info: dict, i: int) -> dict:
    """Env i's entries of a batched info, as a batch of one (what `first_env` reads)."""
    return {key: info[key][i : i + 1] for key in INFO_KEYS if key in info}


def last_step(obs, info: dict) -> tuple:
    """The observation and info of the step just taken. A vector env resets a finished episode in the same step
    (gymnasium's same-step autoreset): its last observation and info are then under final_obs / final_info."""
    if "final_obs" not in info:
        return obs, info
    done = np.asarray(info["_final_obs"], bool)
    obs = np.array(obs, copy=True)
    obs[done] = np.stack(info["final_obs"][done])
    final = info["final_info"]
    return obs, {key: np.where(done, final[key], info[key]) for key in INFO_KEYS if key in info}


def drop_boxes(obs, dropped: np.ndarray):
    """The box state with the envs `dropped` (a bool each) set to "not seen" (the box zeros; a camera position
    after it is kept); `obs` itself when none is dropped."""
    if not dropped.any():
        return obs
    array = box_array(obs)  # a copy
    array[dropped, :4] = 0.0
    return array


class Selector:
    """`Args.select_every`: validates the live network now and then, and keeps a copy of the one that succeeded
    most on the validation scenes (success, then success at the end; the later on a tie)."""

    def __init__(self, args: Args):
        self.args, self.env = args, None
        self.best, self.best_score, self.checks = None, None, []
        first = args.seed * TRAIN_SEED_STRIDE + VALIDATION_OFFSET
        self.seeds = range(first, first + args.select_episodes)

    def due(self, episodes_done: int) -> bool:
        every = self.args.select_every
        return every > 0 and episodes_done >= self.args.select_from and episodes_done % every == 0

    def check(self, q_network: QNetwork, episodes_done: int):
        if self.env is None:
            self.env = make_env(self.args.env)  # one env of its own: the training env's episodes are unchanged
        greedy = DQNPolicy(
            self.env,
            q_network=q_network,
            with_last_action=self.args.with_last_action,
            avoid_refused=self.args.avoid_refused,
        )
        policy = ExplorePolicy(self.env, then=greedy, look_over=self.args.look_over) if self.args.explore else greedy
        episodes = evaluate(self.env, policy, self.seeds, with_reference=False, progress=False)
        score = (
            float(np.mean([e["success"] for e in episodes])),
            float(np.mean([e["success_final"] for e in episodes])),
        )
        self.checks.append({"episodes": episodes_done, "success": score[0], "success_final": score[1]})
        if self.best_score is None or score >= self.best_score:
            self.best_score, self.best = score, copy.deepcopy(q_network.state_dict())
            self.checks[-1]["kept"] = True

    def close(self):
        if self.env is not None:
            self.env.close()


def update(
    q_network: QNetwork,
    target_network: QNetwork,
    optimizer,
    batch: dict | list[dict],
    args: Args,
    buffer: ReplayBuffer | None = None,
) -> tuple[float, float]:
    """One gradient step on a batch (or one per ensemble member): the TD loss, plus DQfD's margin loss with
    `demo_margin` (on the ensemble's mean, the first batch); returns both. A prioritised batch's TD errors become
    its transitions' priorities in `buffer`."""
    loss, errors = td_loss(q_network, target_network, batch, args.gamma, args.double_dqn, args.huber, True)
    first = batch[0] if isinstance(batch, list) else batch
    if "indices" in first:
        buffer.set_priorities(first["indices"], errors)
    margin = margin_loss(q_network, first, args.demo_margin) if args.demo_margin else torch.zeros(())
    optimizer.zero_grad()
    (loss + margin).backward()
    optimizer.step()
    return loss.item(), margin.item()


def sample(buffer: ReplayBuffer, args: Args, rng, correction: float = 1.0) -> dict | list[dict]:
    """A batch (prioritised with `priority_exponent`, β = `correction`), or with `ensemble_batches` one per
    ensemble member."""
    if args.ensemble_batches:
        return [buffer.sample(args.batch_size, rng) for _ in range(args.ensemble)]
    return buffer.sample(args.batch_size, rng, args.priority_exponent, correction)


def tensorboard_writer(run_dir: str):
    """A TensorBoard `SummaryWriter` on `run_dir`; TensorBoard is optional, so its absence is an error that says
    how to install it."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError as e:
        raise ImportError(
            "--track writes TensorBoard scalars, and TensorBoard is not installed: pip install -e '.[track]' "
            "(or pip install tensorboard)"
        ) from e
    return SummaryWriter(run_dir)


TRACKED = (
    "return",
    "learner_return",
    "success",
    "success_final",
    "focus_held",
    "epsilon",
    "td_loss",
    "margin_loss",
    "learner_steps",
)
"""The per-episode entries of the history that --track writes, under charts/ or losses/, at the episode's
last env step (CleanRL's x axis)."""


def default_run_name(args: Args) -> str:
    shaping = f"_{args.shaping}" if args.shaping != "none" else ""
    link = "_ee" if args.env.with_ee_pos else ""
    return f"{args.env.placement}_{'explore' if args.explore else 'noexplore'}{link}{shaping}_seed{args.seed}"


def train(args: Args, progress: bool = True) -> dict:
    """Train one DQN; returns {"run_dir", "checkpoint", "history" (one dict per episode), "transitions" (stored)}."""
    if args.shaping not in SHAPINGS:
        raise ValueError(f"shaping={args.shaping!r} is not one of: {', '.join(SHAPINGS)}")
    if args.hold_reward and args.end_at_success:
        raise ValueError(
            f"hold_reward={args.hold_reward} pays for time in success, but end_at_success ends a training "
            "episode at its first success: turn end_at_success off (--no-end-at-success)"
        )
    if not 0 <= args.box_dropout < 1:
        raise ValueError(f"box_dropout={args.box_dropout} must be a probability in [0, 1)")
    if not 0 <= args.push_probability <= 1 or args.push_steps < 1:
        raise ValueError(
            f"push_probability={args.push_probability}, push_steps={args.push_steps}: "
            "a probability in [0, 1] and at least 1 step"
        )
    if args.end_learning_rate < 0:
        raise ValueError(f"end_learning_rate={args.end_learning_rate} must be ≥ 0 (0: constant learning_rate)")
    if args.demo_margin_steps < 0:
        raise ValueError(
            f"demo_margin_steps={args.demo_margin_steps} must be ≥ 0 (0: the margin on every demonstration step)"
        )
    if args.fine_as_deployed and not args.env.fine_step_size:
        raise ValueError("fine_as_deployed maps the fine moves onto the six directions: set env.fine_step_size > 0")
    if args.look_over and not args.explore:
        raise ValueError("look_over is the exploration's lead-in: it needs explore")
    if args.env.box_source == "none":
        raise ValueError("the DQN learns on the box state: env.box_source must be ground_truth or fcn")
    if args.episodes % args.num_envs:
        raise ValueError(
            f"episodes={args.episodes} must be a multiple of num_envs={args.num_envs} (rounds of one each)"
        )
    if (
        args.priority_exponent < 0
        or not 0 <= args.priority_correction <= 1
        or (args.priority_exponent and args.ensemble > 1)
    ):
        raise ValueError(
            f"priority_exponent={args.priority_exponent} must be ≥ 0 (0: uniform replay), priority_correction="
            f"{args.priority_correction} in [0, 1], and prioritised replay is for one network (ensemble={args.ensemble})"
        )
    if args.select_every < 0 or (args.select_every and args.select_episodes < 1):
        raise ValueError(
            f"select_every={args.select_every}, select_episodes={args.select_episodes}: "
            "select_every is 0 (off) or a positive episode count, with select_episodes >= 1"
        )
    if args.snapshots < 1 or args.snapshot_every < 1 or args.snapshot_every % args.num_envs:
        raise ValueError(
            f"snapshots={args.snapshots}, snapshot_every={args.snapshot_every}: at least 1 each, snapshot_every a "
            f"multiple of num_envs={args.num_envs} (snapshots are taken between rounds)"
        )
    if (args.snapshots - 1) * args.snapshot_every >= args.episodes:
        raise ValueError(
            f"snapshots={args.snapshots} every {args.snapshot_every} episodes reach before the first of the "
            f"{args.episodes} training episodes: fewer snapshots or a shorter snapshot_every"
        )
    if args.snapshots > 1 and (args.ensemble > 1 or args.select_every):
        raise ValueError(
            "snapshots averages one network's last states: it cannot be combined with ensemble or select_every"
        )
    if args.episodes > VALIDATION_OFFSET:
        raise ValueError(f"episodes={args.episodes} would reach the validation scenes: at most {VALIDATION_OFFSET}")
    # a margin outside [0, 1) is a ValueError here, before anything is built
    hold_limits = margin_limits(args.env.success_fraction, args.env.success_center_tol, args.hold_margin)
    run_dir = os.path.join(args.run_dir, args.run_name or default_run_name(args))
    os.makedirs(run_dir, exist_ok=True)
    writer = tensorboard_writer(run_dir) if args.track else None  # before anything slow: a missing extra fails now
    torch.set_num_threads(1)
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    drop_rng = np.random.default_rng([args.seed, 1])  # its own stream: the other presets' draws are unchanged
    push_rng = np.random.default_rng([args.seed, 2])  # likewise
    n = args.num_envs
    env = make_env(args.env) if n == 1 else make_vec_env(args.env, n, backend="cpu")  # worker processes
    env_actions = num_actions(env)  # 6, 7 with env.stay_action, 12 or 13 with env.fine_step_size
    actions = env_actions - len(FINE) if args.fine_as_deployed else env_actions  # the network's
    to_network = ActionMap(actions, env_actions).to_policy  # the env's action taken -> the network's, to store
    mirror_action = mirrored_actions(actions)
    mirrored_layout = (args.env.with_mask_stats, args.env.with_ee_pos, args.env.with_presence)  # mirror_state's
    state_dim = box_array(env.observation_space.sample()).shape[-1] + (actions if args.with_last_action else 0)

    q_network = QNetwork(state_dim, args.hidden_units, actions, args.ensemble)
    optimizer = torch.optim.Adam(q_network.parameters(), lr=args.learning_rate)
    target_network = QNetwork(state_dim, args.hidden_units, actions, args.ensemble)
    target_network.load_state_dict(q_network.state_dict())
    if not args.target_network:
        target_network = q_network  # bootstrap from the online network itself
    # the ε-greedy learner acts without avoid_refused: it is for the trained agent (measured: docs/control.md §7)
    learner = DQNPolicy(env, q_network=q_network, seed=args.seed, with_last_action=args.with_last_action)
    servo = ServoPolicy(  # after the exploration's hand-over the lead-in is done: the servo does not redo it
        env,
        hold=actions > len(DIRECTIONS),
        hold_limits=hold_limits,
        look_over=args.look_over,
        lead_in=args.look_over and not args.explore,
    )
    mixed = DemoOrLearner(servo, learner)
    actor = ExplorePolicy(env, then=mixed, look_over=args.look_over) if args.explore else mixed
    buffer = ReplayBuffer(args.buffer_size, state_dim)
    windows = [NStepWindow(args.n_step, args.gamma) for _ in range(n)]
    learner_rewards = [LearnerReward(args, args.env.success_fraction, hold_limits) for _ in range(n)]
    trajectories = [Trajectory() for _ in range(n)]

    selector = Selector(args)
    snapshots = []  # (`Args.snapshots`) the network's states to average, oldest first
    history, global_step, start = [], 0, time.time()
    bar = tqdm(total=args.episodes, desc=f"DQN {os.path.basename(run_dir)}", disable=not progress)
    try:
        for first in range(0, args.episodes, n):  # a round: episodes first, ..., first + n - 1, one per env
            episodes = np.arange(first, first + n)
            learner.epsilon = np.array(
                [linear_schedule(args.start_epsilon, args.end_epsilon, args.episodes - 1, e) for e in episodes]
            )
            mixed.demo = episodes < args.demo_episodes
            if args.end_learning_rate:
                lr = linear_schedule(args.learning_rate, args.end_learning_rate, args.episodes - 1, first)
                optimizer.param_groups[0]["lr"] = lr
            correction = linear_schedule(args.priority_correction, 1.0, args.episodes - 1, first)
            seeds = [args.seed * TRAIN_SEED_STRIDE + int(e) for e in episodes]
            obs, info = env.reset(seed=seeds[0] if n == 1 else seeds)
            if args.box_dropout:
                obs = drop_boxes(obs, drop_rng.random(n) < args.box_dropout)
            actor.reset(obs, info)
            for i in range(n):
                trajectories[i].start(env_info(info, i))
                learner_rewards[i].reset(env_info(info, i))
            losses, margins = [], []
            learner_steps, learner_return = np.zeros(n, int), np.zeros(n)
            running = np.ones(n, bool)  # the env's training episode goes on (a finished one idles to the round's end)
            push_drawn, push_left = mixed.demo.copy(), np.zeros(n, int)  # one draw per learner episode
            push_direction, pushed = np.zeros(n, int), np.zeros(n, bool)
            while running.any():
                learner_acts = actor.update(obs).copy() if args.explore else np.ones(n, bool)
                states = learner.state(obs)
                action = actor.act(obs, info)
                forced = push_left > 0
                action, push_left = np.where(forced, push_direction, action), push_left - forced
                acted = mixed.demo | forced  # the state's last direction is the one taken
                learner.last_action[acted] = to_network[action[acted]]
                next_obs, reward, terminated, truncated, info = env.step(action)
                final_obs, final_info = last_step(next_obs, info)  # before a vector env's same-step reset
                if args.box_dropout:  # the same draw for the step's observation and its episode's last one
                    dropped = drop_rng.random(n) < args.box_dropout
                    next_obs, final_obs = drop_boxes(next_obs, dropped), drop_boxes(final_obs, dropped)
                next_states = learner.state(final_obs)
                for i in np.flatnonzero(running):
                    view = env_info(final_info, i)
                    trajectories[i].append(reward[i : i + 1], view)
                    ended = bool(terminated[i]) or (args.end_at_success and bool(first_env(view, "success")))
                    if args.push_probability and learner_acts[i] and not push_drawn[i] and first_env(view, "success"):
                        push_drawn[i] = True
                        if push_rng.random() < args.push_probability:
                            push_left[i], push_direction[i] = args.push_steps, push_rng.integers(len(DIRECTIONS))
                            pushed[i] = True
                    done = ended or bool(truncated[i])
                    reward_now = learner_rewards[i](reward[i : i + 1], view, stayed=action[i] == STAY_INDEX)
                    learner_return[i] += reward_now
                    if learner_acts[i]:  # the script's steps are not the learner's experience
                        stored = to_network[action[i]]
                        ready = windows[i].push(states[i], stored, reward_now, next_states[i], ended, done)
                        for s0, a0, discounted, s_n, final, steps in ready:
                            margin = margin_applies(args, mixed.demo[i], learner_steps[i], steps)
                            buffer.add(s0, a0, discounted, s_n, final, steps, margin)
                            if args.mirror_augment:
                                mirrored = (
                                    mirror_state(s0, *mirrored_layout),
                                    mirror_action[a0],
                                    discounted,
                                    mirror_state(s_n, *mirrored_layout),
                                )
                                buffer.add(*mirrored, final, steps, margin)
                        learner_steps[i] += 1
                    running[i] = not done
                    global_step += 1  # the updates follow the env steps of the episodes, whatever the env count
                    if buffer.size >= args.learning_starts and global_step % args.train_frequency == 0:
                        for _ in range(args.updates_per_step):
                            batch = sample(buffer, args, rng, correction)
                            losses_now = update(q_network, target_network, optimizer, batch, args, buffer)
                            losses.append(losses_now[0])
                            if args.demo_margin:
                                margins.append(losses_now[1])
                    if args.target_network and global_step % args.target_update_steps == 0:
                        target_network.load_state_dict(q_network.state_dict())
                obs = next_obs

            for i, episode in enumerate(episodes):
                metrics = episode_metrics(trajectories[i])
                history.append(
                    {
                        "episode": int(episode),
                        "epsilon": float(learner.epsilon[i]),
                        "learning_rate": float(optimizer.param_groups[0]["lr"]),
                        "learner_steps": int(learner_steps[i]),
                        "learner_return": float(learner_return[i]),
                        "demo": bool(mixed.demo[i]),
                        "pushed": bool(pushed[i]),
                        "td_loss": float(np.mean(losses)) if losses else math.nan,
                        "margin_loss": float(np.mean(margins)) if margins else math.nan,
                        **metrics,
                    }
                )
                if writer is not None:
                    for key in TRACKED:
                        if not math.isnan(history[-1][key]):  # e.g. focus held of an unsuccessful episode
                            group = "losses" if key.endswith("loss") else "charts"
                            writer.add_scalar(f"{group}/{key}", history[-1][key], global_step)
            bar.update(n)
            if selector.due(first + n):
                selector.check(q_network, first + n)
            left = args.episodes - (first + n)
            if args.snapshots > 1 and left % args.snapshot_every == 0 and left < args.snapshots * args.snapshot_every:
                snapshots.append(copy.deepcopy(q_network.member(0).state_dict()))
            bar.set_postfix(
                ret=f"{metrics['return']:.2f}", success=int(metrics["success"]), eps=f"{learner.epsilon[-1]:.3f}"
            )
    finally:
        bar.close()
        env.close()
        selector.close()
        if selector.best is not None:  # the validated network that succeeded most, not the last one
            q_network.load_state_dict(selector.best)
        if args.snapshots > 1 and len(snapshots) == args.snapshots:  # (after Ctrl-C: the last network alone)
            q_network = ensemble_of(q_network, snapshots)
        if writer is not None:
            writer.close()
        checkpoint = os.path.join(run_dir, "q_network.pt")  # also after Ctrl-C: what was learned so far
        save_q_network(checkpoint, q_network, args)
        save_json(
            {
                "config": dataclasses.asdict(args),
                "seconds": time.time() - start,
                "env_steps": global_step,
                "complete": len(history) == args.episodes,
                "selection": selector.checks,
                "history": history,
            },
            os.path.join(run_dir, "history.json"),
        )
    return {"run_dir": run_dir, "checkpoint": checkpoint, "history": history, "transitions": buffer.size}


SHAPED = dict(
    end_at_success=True,
    success_bonus=1.0,
    refusal_penalty=0.1,
    step_cost=0.02,
    shaping="log_fraction_centred",
    shaping_scale=5.0,
    gamma=0.99,
    n_step=5,
    with_last_action=True,
    double_dqn=True,
    mirror_augment=True,
    updates_per_step=2,
)
"""The options of the `shaped` preset (the paper's learner with our learner's reward; see the module docstring)."""

HOLD = {**SHAPED, "end_at_success": False, "hold_reward": 0.2}
"""The options of the `hold` preset: `shaped`, but training episodes go on past success and every later step
in success earns `hold_reward` (docs/control.md)."""

DEMO = {"demo_episodes": 10}
"""Added to a preset: the scripted servo acts the first 10 of its 100 training episodes (docs/control.md)."""

WIDE = {"hidden_units": 128}
"""Added to a preset: 128 hidden units instead of the paper's 20 (docs/control.md §6)."""

HOLD_STAY = {"hold_margin": 0.15, "avoid_refused": True, "env": EnvConfig(stay_action=True, with_mask_stats=True)}
"""Added to a preset: the seventh action `stay`, the mask's share and centroid offset in the state, time in
success paid only well inside it, and no refused action repeated at once (docs/control.md §7)."""

DECAY = {"end_learning_rate": 1e-4}
"""Added to a preset: the learning rate decayed linearly from 1e-3 to 1e-4 over the training episodes, like ε, so
that the last episodes move the network less (docs/control.md §7 and §9)."""

FINE_AS_DEPLOYED = {
    **HOLD_STAY,
    "env": HOLD_STAY["env"].replace(fine_step_size=DQN_FINE_STEP_SIZE),
    "fine_as_deployed": True,
}
"""Added to a preset in place of HOLD_STAY: HOLD_STAY with the fine moves of the deployed agent in training too, the
network's seven actions taking half steps near success as they will when it acts (`Args.fine_as_deployed`;
docs/control.md §12)."""

PRESETS = {
    "paper": ("the paper's configuration", Args()),
    "shaped": ("the paper's network and schedule, learning from a shaped reward that ends at success", Args(**SHAPED)),
    "hold": ("shaped, but episodes go on past success and time in success pays", Args(**HOLD)),
    "shaped_demo": ("shaped, the servo acting its first 10 training episodes", Args(**SHAPED, **DEMO)),
    "hold_demo": ("hold, the servo acting its first 10 training episodes", Args(**HOLD, **DEMO)),
    "hold_demo_wide": ("hold_demo with 128 hidden units", Args(**HOLD, **DEMO, **WIDE)),
    "hold_stay": (
        "hold_demo_wide that stays: stay, the mask stats, time in success paid well inside it",
        Args(**HOLD, **DEMO, **WIDE, **HOLD_STAY),
    ),
    "hold_stay_decay": (
        "hold_stay with the learning rate decayed to 1e-4 over training, a steadier last network",
        Args(**HOLD, **DEMO, **WIDE, **HOLD_STAY, **DECAY),
    ),
    "hold_stay_fine": (
        "hold_stay_decay trained with the fine moves near success, as it is deployed (the shipped agent's)",
        Args(**HOLD, **DEMO, **WIDE, **FINE_AS_DEPLOYED, **DECAY),
    ),
}

if __name__ == "__main__":
    # the command line's learning curve; train() itself imports no plotting
    from mani_active_vision.evaluation.report import plot_curves

    result = train(tyro.extras.overridable_config_cli(PRESETS))
    curve = os.path.join(result["run_dir"], "learning_curve.png")
    plot_curves(
        {os.path.basename(result["run_dir"]): [[h["return"] for h in result["history"]]]}, curve, "episode return"
    )
    print(f"checkpoint: {result['checkpoint']}\nlearning curve: {curve}")
