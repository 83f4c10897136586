"""Policies with one interface, over `DiscreteDirections` actions, acting on the box state.

A policy is built by `make_policy(name, env, **kwargs)` on the env it will act in: a `DiscreteDirections`
env wrapped in `BoxState` (ground-truth or FCN box; batched or not), and then:
- `policy.reset(obs, info)` at the start of every episode (for batched envs: whenever any env resets),
- `policy.act(obs, info) -> np.ndarray` of action indices (N,) int64, one per env (`action_names_for`).
`obs` and `info` are what the wrapped env returned; `obs[..., :4]` is the target's box (x, y, w, h),
zeros when the target is not seen. Names: see POLICIES.

- `random`: uniform directions (a lower bound).
- `servo`: scripted; sweeps (orbits) until the box appears, centres it, then approaches. The sweep
  reverses when a step is refused (joint 1 at its limit).
- `explore`: the paper's scripted exploration with its hand-over rule: it orbits the robot's axis at the
  search height until the target is seen once, then the policy named `then` acts for the rest of the
  episode (the paper: DQN takes over). `then=None` keeps exploring (a baseline that only searches).
- `dqn`: a trained `agents.dqn` Q-network, greedy (or ε-greedy with `epsilon`).
- `memory`: the recurrent agent of `agents.search` (a GRU over the box, the camera's commanded position and
  its previous action): it searches, centres and holds with no script; its state is reset by `reset`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from mani_active_vision.agents.q_network import load_q_network
from mani_active_vision.agents.recurrent_network import STATE_DIMS, features, load_agent
from mani_active_vision.directions import (
    DIRECTIONS,
    FINE,
    FINE_AREA,
    FINE_NEAR_CENTRE,
    STAY,
    action_count,
    action_names,
    action_names_for,
)

LEFT, RIGHT, FORWARD, BACKWARD, UP, DOWN = (
    DIRECTIONS.index(d) for d in ("left", "right", "forward", "backward", "up", "down")
)
STAY_INDEX = action_names(stay_action=True).index(STAY)
FINE_ZONE = (FINE_NEAR_CENTRE, FINE_AREA[0])
"""Where the env has the fine moves (env.fine_step_size), the servo and the DQN take them near success: the
target's box centre within the env's `fine_near_centre` of the image's centre (default `directions.FINE_NEAR_CENTRE`,
0.3; success: 0.15) and the box covering from the env's `fine_from_area` (default 0.02) up to 0.25 of the image
(`directions.FINE_AREA`; success needs the target's own pixels to cover 5%). There a full step passes over the few
views in success; elsewhere (far, off-centre, pushed too close) half steps only cost time (docs/control.md §11,
§18, §32). The default zone, as (centre, from_area); a policy reads its env's (`fine_zone`)."""


BORDER = 1 / 128
"""a box edge this close to the image's (a fraction of its side: one pixel at 128²) touches it"""


def near_target(box: np.ndarray, zone: tuple[float, float] = FINE_ZONE) -> np.ndarray:
    """(N,) bool: the boxes (N, 4+) that are near success, where the fine moves are taken: the centre within
    `zone`'s first number of the image's, the box covering from its second up to `FINE_AREA`'s last (`FINE_ZONE`)."""
    centre, from_area = zone
    x, y, w, h = box[:, 0], box[:, 1], box[:, 2], box[:, 3]
    area = w * h
    centred = (np.abs(x + w / 2 - 0.5) <= centre) & (np.abs(y + h / 2 - 0.5) <= centre)
    return (area >= from_area) & (area <= FINE_AREA[1]) & centred


def cut_by_border(box: np.ndarray) -> np.ndarray:
    """(N,) bool: the boxes (N, 4+) whose edge touches the image's border (within `BORDER`)."""
    x, y, w, h = box[:, 0], box[:, 1], box[:, 2], box[:, 3]
    return (x <= BORDER) | (y <= BORDER) | (x + w >= 1 - BORDER) | (y + h >= 1 - BORDER)


def too_close(box: np.ndarray, area: float) -> np.ndarray:
    """(N,) bool: the boxes (N, 4+) that touch the image's border (`cut_by_border`) and cover at least `area` of
    the image: the target pushed too close and cut, where a DQN steps back (`EnvConfig.back_when_close`; 0: never)."""
    w, h = box[:, 2], box[:, 3]
    return (area > 0) & (w > 0) & cut_by_border(box) & (w * h >= area)


def looks_in_success(box: np.ndarray, success_fraction: float, center_tol: float) -> np.ndarray:
    """(N,) bool: the box states (N, 7+), the mask stats last (`EnvConfig.with_mask_stats`: share, dx, dy), that
    show a view in success as the task judges one on the true mask: the mask covers at least `success_fraction`
    of the image, its centroid lies within `center_tol` (of the width) of the centre, its box is not cut by the
    border (`EnvConfig.stay_needs_success`)."""
    share, dx, dy = box[:, -3], box[:, -2], box[:, -1]
    return (box[:, 2] > 0) & ~cut_by_border(box) & (share >= success_fraction) & (np.hypot(dx, dy) <= center_tol)


_REQUIRED = object()


def directions_option(env, name: str, default=_REQUIRED):
    """An option of the env's wrappers (`DiscreteDirections`, `BoxState`; a vector env's first worker's), as its
    policies read it; `default` where no wrapper has it (without one, an AttributeError)."""
    try:
        return env.get_wrapper_attr(name) if hasattr(env, "get_wrapper_attr") else env.get_attr(name)[0]
    except AttributeError:
        if default is _REQUIRED:
            raise
        return default


def back_when_close(env) -> float:
    """The env's `back_when_close` (0 where it has none)."""
    return float(directions_option(env, "back_when_close", 0.0))


def explore_resumes_after(env) -> int:
    """The env's `explore_resumes_after` (0 where it has none)."""
    return int(directions_option(env, "explore_resumes_after", 0))


def candidate_threshold(env) -> float:
    """The env's `BoxState.candidate_threshold`: > 0 where it reports candidates (0 where it has none)."""
    return float(directions_option(env, "candidate_threshold", 0.0))


def stay_needs_success(env) -> bool:
    """The env's `stay_needs_success` (False where it has none)."""
    return bool(directions_option(env, "stay_needs_success", False))


def stay_rule(env, num_actions: int) -> tuple[float, float] | None:
    """The task's success bars (success_fraction, success_center_tol) where the env says that a policy with `stay`
    takes it only where the box's mask stats show success (`EnvConfig.stay_needs_success`); None where it does not,
    or where the policy has no `stay` (`num_actions`: its own)."""
    if num_actions <= len(DIRECTIONS) or not stay_needs_success(env):
        return None
    if not directions_option(env, "with_mask_stats"):
        raise ValueError("stay_needs_success judges success from the mask stats: make the env with_mask_stats")
    return tuple(float(directions_option(env, name)) for name in ("success_fraction", "success_center_tol"))


def rule_out_stay(scores: torch.Tensor, box: np.ndarray, rule: tuple[float, float]) -> torch.Tensor:
    """`scores` (N, actions) with `stay` set to -inf where the box states (N, 7+) do not show success by `rule`
    (`stay_rule`, `looks_in_success`): a stay leaves the state as it was, so a policy that stays off success would
    stay there to the episode's end."""
    scores[torch.as_tensor(~looks_in_success(box, *rule)), STAY_INDEX] = -torch.inf
    return scores


def fine_zone(env) -> tuple[float, float]:
    """The env's `fine_near_centre` and `fine_from_area` (`DiscreteDirections`'; a vector env's first worker's),
    where its policies take the fine moves (`near_target`); the default for an env without them, where it is never
    used."""
    if num_actions(env) <= len(DIRECTIONS) + 1:
        return FINE_ZONE
    return float(directions_option(env, "fine_near_centre")), float(directions_option(env, "fine_from_area"))


def box_array(obs) -> np.ndarray:
    """The box state as a (N, 4 or 7) float numpy array, from a batched torch or an unbatched numpy obs."""
    if isinstance(obs, dict):
        raise TypeError("policies act on the box state: wrap the env in mani_active_vision.box_state.BoxState")
    array = obs.detach().cpu().numpy() if isinstance(obs, torch.Tensor) else np.asarray(obs)
    return np.atleast_2d(array).astype(np.float32)


def sweep_moves(env) -> np.ndarray | None:
    """Where the env says so (`EnvConfig.sweep_retraces`), each of its actions' (forward, up) in full steps, for a
    sweep that undoes an approach before it orbits on (`Sweep.moved`); None where it does not."""
    if not directions_option(env, "sweep_retraces", False):
        return None
    names = action_names_for(num_actions(env))
    scale = float(directions_option(env, "fine_step", 0.0)) / float(directions_option(env, "step_size"))
    axes = {"forward": (1, 0), "backward": (-1, 0), "up": (0, 1), "down": (0, -1)}
    return np.array(
        [np.multiply(axes.get(n.removesuffix("_fine"), (0, 0)), scale if n in FINE else 1.0) for n in names]
    )


def num_actions(env) -> int:
    """How many discrete actions the env takes: 6 directions, 7 with `stay`, 12 or 13 with the fine moves
    (`action_names_for`; batched or not)."""
    return action_count(env.action_space)


def info_values(info, key: str, num_envs: int) -> np.ndarray:
    """`info[key]` (e.g. "target_fraction") per env as a numpy array (N,)."""
    values = info[key]
    values = values.cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    return np.atleast_1d(values).reshape(num_envs)


def info_flags(info, key: str, num_envs: int) -> np.ndarray:
    """`info[key]` (e.g. "refused", "success") per env as bools (False at reset, when `info` lacks it)."""
    if not info or key not in info:
        return np.zeros(num_envs, dtype=bool)
    return info_values(info, key, num_envs).astype(bool)


def margin_limits(success_fraction: float, success_center_tol: float, margin: float) -> tuple[float, float]:
    """The target's least share and largest centre offset for success with `margin` (0 <= m < 1): ((1 + m) times
    the success share, (1 - m) times the centring tolerance)."""
    if not 0 <= margin < 1:
        raise ValueError(f"margin={margin} must be in [0, 1)")
    return (1 + margin) * success_fraction, (1 - margin) * success_center_tol


def in_success_with_margin(info, num_envs: int, limits: tuple[float, float]) -> np.ndarray:
    """Per env: the task reports success and the target's share is at least `limits[0]` and its centre offset at
    most `limits[1]` (`margin_limits`), from the ground truth's `info`: well inside success, where a learner that
    tells success's edge only roughly can still stay."""
    inside = info_flags(info, "success", num_envs)
    if inside.any() and limits[0] > 0:  # a limit that restricts nothing is not read
        inside &= info_values(info, "target_fraction", num_envs) >= limits[0]
    if inside.any() and limits[1] < math.inf:
        inside &= info_values(info, "target_center_offset", num_envs) <= limits[1]
    return inside


def one_hot(actions: np.ndarray, num_actions: int) -> np.ndarray:
    """(N, num_actions) float32: a DQN's previous action in its state; zeros where there is none (-1) or it is
    not one of the network's actions (a six-direction DQN's `stay`)."""
    return (np.asarray(actions)[:, None] == np.arange(num_actions)).astype(np.float32)


def env_actions(network_actions: int, env_actions: int, fine: bool = True) -> np.ndarray:
    """For each of a Q-network's actions, the env's action index: the same action, or with `fine`, where the env
    has the fine moves and the network does not, the fine move of each direction (`stay` stays)."""
    network, env = action_names_for(network_actions), action_names_for(env_actions)
    added = FINE[0] in env and FINE[0] not in network
    names = [f"{name}_fine" if fine and added and name in DIRECTIONS else name for name in network]
    missing = [name for name in names if name not in env]
    if missing or (not added and network_actions != env_actions):
        raise ValueError(
            f"the Q-network has {network_actions} actions, the env takes {env_actions} ({network} and {env}): train "
            "and act with the same stay_action (the env may add the fine moves, fine_step_size, to a network's six)"
        )
    return np.array([env.index(name) for name in names])


class ActionMap:
    """A learned policy's own actions (the six directions, and `stay` if it has it) as the env's: the same
    actions, or where the env has the fine moves and the policy does not, the fine moves while the box is near
    success (`near_target`). `to_env` and `to_env_full` are the two tables (`env_actions`); `to_policy` maps each
    env action back to the policy's (a fine move to its direction), for a learner that stores its own actions."""

    def __init__(self, policy_actions: int, env_actions_count: int, zone: tuple[float, float] = FINE_ZONE):
        self.zone = zone
        self.to_env = env_actions(policy_actions, env_actions_count)
        self.to_env_full = env_actions(policy_actions, env_actions_count, fine=False)
        self.fine = not np.array_equal(self.to_env, self.to_env_full)
        self.to_policy = np.full(env_actions_count, -1)  # every env action is one of the two tables'
        self.to_policy[self.to_env_full] = self.to_policy[self.to_env] = np.arange(policy_actions)

    def __call__(self, action: np.ndarray, obs) -> np.ndarray:
        if not self.fine:  # no fine moves in the env: nothing to decide per step
            return self.to_env_full[action]
        return np.where(near_target(box_array(obs), self.zone), self.to_env[action], self.to_env_full[action])


def rule_out_refused(q: torch.Tensor, refused: np.ndarray, last_action: np.ndarray) -> torch.Tensor:
    """`q` (N, actions) with each env's last action set to -inf where the controller has just refused it: a
    refused step leaves the state as it was, so a memoryless greedy policy would repeat it (`avoid_refused`)."""
    again = np.flatnonzero(refused & (last_action >= 0) & (last_action < q.shape[1]))
    q[again, last_action[again]] = -torch.inf
    return q


class RandomPolicy:
    """Uniformly random actions (a lower bound)."""

    def __init__(self, env, seed: int = 0):
        self.num_envs = env.unwrapped.num_envs
        self.num_actions = num_actions(env)
        self.rng = np.random.default_rng(seed)

    def reset(self, obs, info):
        pass

    def act(self, obs, info) -> np.ndarray:
        return self.rng.integers(0, self.num_actions, size=self.num_envs)


LOOK_OVER = (UP,) * 3 + (FORWARD,) * 6
"""A sweep's lead-in for scenes with occluders: to the workspace's top, then 6 steps forward, so that the orbit
runs at radius ~0.45 m and height ~0.79 m, above the 50 cm panels. From there some view within ±30° of the
target's azimuth shows it whole in 34 of the 37 of 50 held-out scenes where a panel hides it from the search
pose (`baselines/occlusion.py --rings`); 8 steps forward (0.50 m, 0.70 m) show all 37, but the servo after them
found fewer targets (0.54 against 0.60 of 50 episodes: a longer lead-in and a slower orbit; docs/task.md#occluders)."""

LOOK_OVER_TURN = 19
"""Orbit steps after LOOK_OVER before the sweep first turns back: the objects lie within ±155° of azimuth
(`ActiveVisionFind.placement_azimuth`) and the camera sees ~35° to either side, so at 6.4° a step the far side
is reached at ~120°, well before joint 1's limit (170°) would turn it."""

SWEEP_TURN = 14
"""Orbit steps from the search pose before `ExplorePolicy(first_turn=SWEEP_TURN)` first turns back: the objects lie
within ±155° of azimuth and the camera sees ~20° of azimuth to either side at their distance, so at 9.5° a step one
side has been seen by ~134°, three steps before joint 1's limit would turn the orbit. Teaching the memory agent
(docs/search.md#a-sweep-that-turns-back-at-the-objects-range)."""


OVER_ROW = 0.7
"""`ServoPolicy(look_over=True)`: the image row (0 top, 1 bottom) the target is kept above while its box is small,
so that the camera looks over a panel in front of it (measured: docs/task.md#occluders)."""
OVER_NEAR = 0.05
"""... until its box covers this share of the image; then it is centred."""
OVER_FILLS = 0.36
"""... and a box covering more than this share (or spanning the image) is backed away from."""
OVER_RETREAT = 0.15
"""... and a box covering at least this share but lying below the centring band is retreated from level: a step back
(along the pitched axis: back and up), then one down; where the step back is refused (a panel behind), down. Stepping
down alone brings such a target up the image but nearer, until it is cut by the image's bottom; the servo then
cycled between down, a refused step back and up (measured: docs/task.md#a-level-retreat-from-a-low-near-target-2026-12-08-adopted)."""


class Sweep:
    """Orbit one way around the robot's axis; turn back when a step is refused (at joint 1's limit) or, with
    `first_turn`, after that many orbit steps the first time. With a `lead_in` (directions, e.g. LOOK_OVER), take
    those first. With `moves` (`sweep_moves`, where the env has `sweep_retraces`) its owner reports the actions it
    takes (`moved`), and the sweep first steps back the forward and up/down steps taken off the orbit (an approach
    to a box since lost), then orbits on (docs/control.md §36)."""

    def __init__(
        self,
        num_envs: int,
        first: int = LEFT,
        lead_in: tuple[int, ...] = (),
        first_turn: int = 0,
        moves: np.ndarray | None = None,
    ):
        self.first = first
        self.lead_in = np.asarray(lead_in, dtype=np.int64)
        self.first_turn = first_turn
        self.direction = np.full(num_envs, first)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self.turned = np.zeros(num_envs, dtype=bool)
        self.moves = moves  # (actions, 2): each env action's (forward, up) in full steps; None: no retrace
        self.away = np.zeros((num_envs, 2))  # the camera's (forward, up) from the orbit, in full steps
        self.last_move = np.zeros((num_envs, 2))
        self.retrace = np.zeros(num_envs, dtype=bool)  # this step's sweep action undoes the approach
        self.retraced = np.zeros(num_envs, dtype=bool)  # the owner took it at the last step
        self.action = np.zeros(num_envs, dtype=np.int64)  # this step's sweep action
        self.led = np.zeros(num_envs, dtype=bool)  # this step's sweep action is the lead-in's

    @classmethod
    def looking_over(cls, num_envs: int, first: int = LEFT) -> Sweep:
        """The sweep for scenes with occluders: LOOK_OVER, then an orbit that first turns after LOOK_OVER_TURN."""
        return cls(num_envs, first, LOOK_OVER, LOOK_OVER_TURN)

    def reset(self):
        self.direction[:] = self.first
        self.steps[:] = 0
        self.turned[:] = False
        self.away[:] = 0
        self.last_move[:] = 0
        self.retrace[:] = False
        self.retraced[:] = False

    def moved(self, action: np.ndarray) -> None:
        """Count the env actions (N,) the owner takes this step, so that the sweep can first undo an approach that
        left the orbit (`moves`; the refusal of a step is taken back at the next `act`)."""
        if self.moves is None:
            return
        self.retraced = self.retrace & (action == self.action)
        self.last_move = self.moves[action] * ~self.led[:, None]  # the lead-in's moves make the orbit's height
        self.away += self.last_move

    def _refused(self, refused: np.ndarray) -> None:
        """Take back the last step's move where it was refused; a refused retrace step stops undoing that way."""
        if self.moves is None:
            return
        self.away -= self.last_move * refused[:, None]
        stuck = refused & self.retraced
        self.away[stuck] = np.where(self.last_move[stuck] != 0, 0, self.away[stuck])

    def _retrace(self, action: np.ndarray) -> np.ndarray:
        """`action` with a step back toward the orbit where the camera has left it by half a step or more."""
        if self.moves is None:
            return action
        forward, up = self.away[:, 0], self.away[:, 1]
        back = np.abs(forward) >= 0.5
        level = ~back & (np.abs(up) >= 0.5)
        action[back] = np.where(forward[back] > 0, BACKWARD, FORWARD)
        action[level] = np.where(up[level] > 0, DOWN, UP)
        self.retrace = back | level
        return action

    def leading(self) -> np.ndarray:
        """(N,) bool: the next action is the lead-in's (a sighting does not cut it short: `ExplorePolicy`)."""
        return self.steps < len(self.lead_in)

    def act(self, info) -> np.ndarray:
        refused = info_flags(info, "refused", len(self.direction))
        self._refused(refused)
        # a refusal turns the orbit only when the refused step was an orbit step, not the lead-in's or a retrace's
        turn = refused & (self.steps > len(self.lead_in)) & ~self.retraced
        if self.first_turn:
            turn |= (self.steps - len(self.lead_in) == self.first_turn) & ~self.turned
        self.direction[turn] = np.where(self.direction[turn] == LEFT, RIGHT, LEFT)
        self.turned |= turn
        action = self._retrace(self.direction.copy())
        leading = self.leading()
        action[leading] = self.lead_in[self.steps[leading]]
        self.retrace &= ~leading
        self.action, self.led = action.copy(), leading  # the owners take the lead-in whole
        self.steps += 1
        return action


CANDIDATE_MEMORY = 3
"""`Candidates`: steps a candidate is approached after it was last reported: the verifier's score of a small target
flickers around the candidate bar from frame to frame."""
CANDIDATE_BUDGET = 10
"""... and steps of approach per episode at most: a look-alike is approached at most this long (docs/control.md §34)."""


class Candidates:
    """Where the env reports candidates (`info["candidate_box"]`: regions the FCN's verifier turned away, but not by
    much; `EnvConfig.fcn_candidate_threshold`), the box to approach in each env: the latest candidate, for
    `CANDIDATE_MEMORY` steps after it was last reported, at most `CANDIDATE_BUDGET` steps per episode. Approached,
    a target seen too small to tell grows until the verifier accepts it; a look-alike is dropped once the verifier's
    score falls (docs/control.md §34)."""

    def __init__(self, num_envs: int):
        self.box = np.zeros((num_envs, 4), dtype=np.float32)
        self.left = np.zeros(num_envs, dtype=np.int64)  # steps of approach left since the last report
        self.spent = np.zeros(num_envs, dtype=np.int64)  # steps of approach taken this episode

    def reset(self):
        self.box[:] = 0
        self.left[:] = 0
        self.spent[:] = 0

    def update(self, info, free: np.ndarray) -> np.ndarray:
        """(N,) bool: the envs that approach their candidate (`box`) this step, of those `free` to (e.g. nothing
        seen); all False where the env reports no candidates."""
        if "candidate_box" not in info:
            return np.zeros(len(self.box), dtype=bool)
        reported = box_array(info["candidate_box"])
        new = (reported[:, 2] > 0) & free
        self.box[new] = reported[new]
        self.left = np.where(new, CANDIDATE_MEMORY, np.maximum(self.left - 1, 0))
        approach = free & (self.left > 0) & (self.spent < CANDIDATE_BUDGET)
        self.spent += approach
        return approach


class ServoPolicy:
    """Scripted servo on the box: sweep until seen, centre the box (orbit for x, up/down for y) within
    `center_tol`, then step forward (zoom in). The sweep reverses on a refused step.

    With `hold` it takes `stay` (the env needs `stay_action`) while the task reports success: privileged
    (`info["success"]` is the ground truth), a teacher for the DQN's demonstrations that shows holding. With
    `hold_limits` (`margin_limits`) it stays only well inside success (`in_success_with_margin`).

    With `look_over` (scenes with occluders) its sweep starts with LOOK_OVER and it approaches from above: a
    panel stands in front of the target, and the centred line of sight (60° down) passes through it, so the
    target is kept low in the image (`OVER_ROW`) until its box covers `OVER_NEAR` of the image, by which time
    the camera is past the panel. It also backs off a box that fills the view, does not repeat a refused step
    (it goes forward after a refused up or down, else up) and does not turn back across the target at once: close up,
    one orbit step moves the box by more than the centring tolerance (docs/task.md#occluders). A near target low in
    the image is retreated from level (`OVER_RETREAT`). `lead_in=False`
    leaves the lead-in out, for a servo that takes over after an exploration that has looked over already.

    With `fine` it serves with the fine moves where the env has them (env.fine_step_size) while the box is near
    success (`near_target`); its sweep keeps the full step (docs/control.md §11).

    Where the env reports candidates (`Candidates`), it serves a candidate as it would the box while the box is
    empty."""

    def __init__(
        self,
        env,
        center_tol: float = 0.1,
        first_sweep: str = "left",
        hold: bool = False,
        hold_limits: tuple[float, float] = (0.0, math.inf),
        look_over: bool = False,
        lead_in: bool | None = None,
        fine: bool = True,
    ):
        self.num_envs = env.unwrapped.num_envs
        names = action_names_for(num_actions(env))
        self.fine_offset = names.index(FINE[0]) if fine and FINE[0] in names else 0  # FINE is in DIRECTIONS' order
        self.zone = fine_zone(env)
        self.center_tol = center_tol
        lead_in = look_over if lead_in is None else lead_in
        first = DIRECTIONS.index(first_sweep)
        self.sweep = Sweep.looking_over(self.num_envs, first) if lead_in else Sweep(self.num_envs, first)
        self.sweep.moves = sweep_moves(env)
        if hold and num_actions(env) == len(DIRECTIONS):
            raise ValueError("ServoPolicy(hold=True) takes `stay`: make the env with stay_action")
        self.hold, self.hold_limits = hold, hold_limits
        self.look_over = look_over
        self.last_action = np.full(self.num_envs, -1)
        self.retreating = np.zeros(self.num_envs, dtype=bool)  # the last step back began a level retreat
        self.candidates = Candidates(self.num_envs)

    def reset(self, obs, info):
        self.sweep.reset()
        self.last_action[:] = -1
        self.retreating[:] = False
        self.candidates.reset()

    def act(self, obs, info) -> np.ndarray:
        box = box_array(obs)
        approach = self.candidates.update(info, box[:, 2] == 0)
        if approach.any():
            box = box.copy()
            box[approach, :4] = self.candidates.box[approach]
        x, y, w, h = box[:, :4].T
        leading = self.sweep.leading()
        sweep = self.sweep.act(info)  # called every step so that refusals while sweeping turn it
        cx, cy = x + w / 2, y + h / 2
        action = np.full(self.num_envs, FORWARD)
        lowest = 0.5 + self.center_tol
        if self.look_over:
            lowest = np.where(w * h < OVER_NEAR, OVER_ROW + self.center_tol, lowest)
        off_y = (cy < 0.5 - self.center_tol) | (cy > lowest)
        action[off_y] = np.where(cy[off_y] < 0.5, UP, DOWN)  # raising the camera moves the object down the image
        off_x = np.abs(cx - 0.5) > self.center_tol
        turn = np.where(cx < 0.5, LEFT, RIGHT)
        if self.look_over:
            back = np.where(turn == LEFT, self.last_action == RIGHT, self.last_action == LEFT)
            off_x &= ~back  # not straight back after an orbit step
        action[off_x] = turn[off_x]
        served = (w > 0) & ~leading  # a lead-in is finished before the target is served
        if self.look_over:
            refused = info_flags(info, "refused", self.num_envs)
            low_near = served & (cy > lowest) & (w * h >= OVER_RETREAT)
            back_refused = refused & (self.last_action == BACKWARD)
            down = served & self.retreating & (self.last_action == BACKWARD)  # the retreat's second half
            action[low_near & ~back_refused] = BACKWARD
            action[(low_near & back_refused) | down] = DOWN
            self.retreating = low_near & ~back_refused & ~down
            fills = ((x <= 0.01) & (x + w >= 0.99)) | ((y <= 0.01) & (y + h >= 0.99)) | (w * h > OVER_FILLS)
            action[fills] = BACKWARD
            again = served & refused & (action == self.last_action)
            action[again] = np.where(np.isin(action[again], (UP, DOWN)), FORWARD, UP)
        action[~served] = sweep[~served]
        self.last_action[:] = action
        if self.fine_offset:
            action[served & near_target(box, self.zone)] += self.fine_offset
        if self.hold:
            action[in_success_with_margin(info, self.num_envs, self.hold_limits)] = STAY_INDEX
        self.sweep.moved(action)
        return action.astype(np.int64)


class ExplorePolicy:
    """The paper's exploration routine with hand-over: orbit (reversing on refusals) until the target is
    seen; from then on, for the rest of the episode, the policy `then` acts (none: keep orbiting).

    `handed_over` (N,) bool says which envs the explorer has handed over this episode: a learner uses it
    to tell its own steps from the script's. With `look_over` the orbit starts with LOOK_OVER (scenes with
    occluders); by default, where a DQN checkpoint was trained after that lead-in (its `look_over`). With
    `first_turn` (e.g. SWEEP_TURN) the orbit first turns back after that many steps, not at joint 1's limit.
    Where the env says so (`EnvConfig.explore_resumes_after`), an env whose box state has been empty (nothing seen,
    nothing held) for that many steps after the hand-over is handed back to the orbit until the next sighting: a
    hand-over on a look-alike then costs a detour, not the episode (docs/control.md §31). Where the env reports
    candidates (`Candidates`), the orbit stops to approach one, as the servo would, until it is seen or dropped.
    """

    def __init__(
        self, env, then=None, seed: int = 0, look_over: bool | None = None, first_turn: int = 0, **then_kwargs
    ):
        self.num_envs = env.unwrapped.num_envs
        if isinstance(then, str) and then != "none":  # a name in POLICIES, else a policy object (or None)
            then = make_policy(then, env, **({"seed": seed} if then in ("random", "dqn") else {}), **then_kwargs)
        self.then = None if then == "none" else then
        if look_over is None:
            look_over = bool(getattr(self.then, "config", {}).get("look_over", False))
        if first_turn < 0 or (first_turn and look_over):
            raise ValueError(f"first_turn={first_turn} must be >= 0, and 0 with look_over (LOOK_OVER_TURN)")
        self.sweep = Sweep.looking_over(self.num_envs) if look_over else Sweep(self.num_envs, first_turn=first_turn)
        self.sweep.moves = sweep_moves(env)
        self.handed_over = np.zeros(self.num_envs, dtype=bool)
        self.resumes_after = explore_resumes_after(env)
        self.unseen_for = np.zeros(self.num_envs, dtype=np.int64)  # steps in a row with an empty box
        self.candidates = Candidates(self.num_envs)
        self.approach = ServoPolicy(env) if candidate_threshold(env) else None  # acts on a candidate's box only

    def reset(self, obs, info):
        self.sweep.reset()
        self.candidates.reset()
        self.handed_over[:] = False
        self.unseen_for[:] = 0
        if self.then is not None:
            self.then.reset(obs, info)

    def update(self, obs):
        """Latch the hand-over for envs whose target is in view now, the sweep's lead-in (if any) done (and, with
        `resumes_after`, release it where the box has been empty that long); returns `handed_over`."""
        if self.then is not None:
            seen = box_array(obs)[:, 2] > 0
            if self.resumes_after:
                self.unseen_for = np.where(seen, 0, self.unseen_for + 1)
                self.handed_over &= self.unseen_for < self.resumes_after
            self.handed_over |= seen & ~self.sweep.leading()
        return self.handed_over

    def act(self, obs, info) -> np.ndarray:
        handed_over = self.update(obs)  # before the sweep counts this step
        approach = self.candidates.update(info, ~handed_over & ~self.sweep.leading())
        action = self.sweep.act(info)
        if self.approach is not None and approach.any():
            box = box_array(obs).copy()
            box[:, :4] = self.candidates.box
            action = np.where(approach, self.approach.act(box, {}), action)
        if handed_over.any():
            action = np.where(handed_over, self.then.act(obs, info), action)
        self.sweep.moved(action)
        return action.astype(np.int64)


class DQNPolicy:
    """A Q-network: argmax Q, or ε-greedy with `epsilon`. From an `agents.dqn` checkpoint file, or (while
    training) the live `q_network` itself. With `with_last_action` (read from the checkpoint's config) the
    network's state is the box followed by a one-hot of this policy's own previous action (zeros at the
    start of an episode): `state(obs)`. The env takes the network's actions (6, or 7 with `stay`), and may add
    the fine moves (`ActionMap`).
    With `avoid_refused` (read from the checkpoint's config too) a greedy action the controller has just refused
    is not taken again at once: a refused step leaves the state as it was, so a memoryless greedy policy would
    repeat it to the episode's end (docs/control.md §7). Where the env says so (`EnvConfig.back_when_close`,
    `too_close`) it steps backward while the box, seen this step (not held: `info["box_held"]`), is cut by the
    border and large: views too close that the networks never learnt from (docs/control.md §19–20). Where the env
    says so (`EnvConfig.stay_needs_success`) a network with `stay` takes it only where the box's mask stats show a
    view in success (`looks_in_success`, the task's own bars); a stay leaves the state as it was, so a greedy
    network that stays off success would stay to the episode's end (docs/control.md §21).

    In an env with the fine moves (env.fine_step_size) a network trained on the six directions (and `stay`) takes
    the fine move of each direction it chooses while the box is near success (`near_target`): there half a step
    lands on views in success that a full one passes over (docs/control.md §11; `ActionMap`). `last_action`
    and the state's one-hot are the network's own indices; `act` returns the env's."""

    def __init__(
        self,
        env,
        checkpoint: str | None = None,
        epsilon: float = 0.0,
        seed: int = 0,
        q_network=None,
        with_last_action: bool = False,
        avoid_refused: bool = False,
    ):
        if (checkpoint is None) == (q_network is None):
            raise ValueError("DQNPolicy needs exactly one of checkpoint= (a file) or q_network= (a live network)")
        self.num_envs = env.unwrapped.num_envs
        self.q_network, self.config = (q_network, {}) if q_network is not None else load_q_network(checkpoint)
        self.with_last_action = bool(self.config.get("with_last_action", with_last_action))
        self.avoid_refused = bool(self.config.get("avoid_refused", avoid_refused))
        self.last_action = np.full(self.num_envs, -1)
        self.num_actions = self.q_network.num_actions
        self.action_map = ActionMap(self.num_actions, num_actions(env), fine_zone(env))
        self.back_when_close = back_when_close(env)
        self.stay_rule = stay_rule(env, self.num_actions)
        state_dim = box_array(env.observation_space.sample()).shape[-1] + (
            self.num_actions if self.with_last_action else 0
        )
        if state_dim != self.q_network.state_dim:
            raise ValueError(
                f"checkpoint {checkpoint!r} expects a state of {self.q_network.state_dim} numbers "
                f"(with_ee_pos={self.config.get('env', {}).get('with_ee_pos')}), the env gives {state_dim}"
            )
        self.epsilon = epsilon
        self.rng = np.random.default_rng(seed)

    def reset(self, obs, info):
        self.last_action[:] = -1

    def state(self, obs) -> np.ndarray:
        """The network's input (N, state_dim): the box state, and the last direction one-hot if used."""
        box = box_array(obs)
        if not self.with_last_action:
            return box
        return np.concatenate([box, one_hot(self.last_action, self.num_actions)], 1)

    def act(self, obs, info) -> np.ndarray:
        with torch.no_grad():
            q = self.q_network(torch.as_tensor(self.state(obs)))
        if self.avoid_refused:
            q = rule_out_refused(q, info_flags(info, "refused", self.num_envs), self.last_action)
        if self.stay_rule:
            q = rule_out_stay(q, box_array(obs), self.stay_rule)
        action = q.argmax(-1).numpy().astype(np.int64)
        if self.back_when_close:  # on a box seen now: a held one does not change as the camera steps back
            close = too_close(box_array(obs), self.back_when_close) & ~info_flags(info, "box_held", self.num_envs)
            action[close] = BACKWARD
        explore = self.rng.random(self.num_envs) < self.epsilon
        action[explore] = self.rng.integers(0, self.num_actions, size=int(explore.sum()))
        self.last_action[:] = action
        return self.action_map(action, obs)


class MemoryPolicy:
    """The recurrent actor-critic of `agents.search` (`agents.recurrent_network`): from a checkpoint file or
    (while training) the live `agent`. Greedy (the most probable action) unless `sample`. Its GRU state and
    its previous action are reset by `reset` (an episode's start) and carried across `act` calls. The env
    must give the box with the camera's commanded position (`EnvConfig(with_ee_pos=True)`: a checkpoint
    trained so sets it) and take the agent's actions; like `DQNPolicy`, in an env with the fine moves it takes
    them near success, and where the env says so (`EnvConfig.stay_needs_success`) it takes `stay` only where the
    box's mask stats show success (`rule_out_stay`; docs/task.md#occluders)."""

    def __init__(self, env, checkpoint: str | None = None, seed: int = 0, agent=None, sample: bool = False):
        if (checkpoint is None) == (agent is None):
            raise ValueError("MemoryPolicy needs exactly one of checkpoint= (a file) or agent= (a live network)")
        self.agent, self.config = (agent, {}) if agent is not None else load_agent(checkpoint)
        self.num_envs = env.unwrapped.num_envs
        self.num_actions = self.agent.num_actions
        self.action_map = ActionMap(self.num_actions, num_actions(env), fine_zone(env))
        box_dim = box_array(env.observation_space.sample()).shape[-1]
        if box_dim not in STATE_DIMS:
            raise ValueError(
                f"the memory agent acts on the box and the camera's commanded position (7 numbers), the env gives "
                f"{box_dim}: make it with EnvConfig(with_ee_pos=True)"
            )
        if self.agent.input_dim != box_dim + 1 + self.num_actions:
            raise ValueError(
                f"the memory agent takes {self.agent.input_dim} inputs, the env's box state gives "
                f"{box_dim + 1 + self.num_actions}: train and act with the same with_mask_stats and with_presence"
            )
        self.stay_rule = stay_rule(env, self.num_actions)
        self.sample = sample
        self.generator = torch.Generator().manual_seed(seed)
        self.state = self.agent.initial_state(self.num_envs)
        self.last_action = np.full(self.num_envs, -1)

    def reset(self, obs, info):
        self.state = self.agent.initial_state(self.num_envs)
        self.last_action[:] = -1

    def act(self, obs, info) -> np.ndarray:
        x = torch.as_tensor(features(box_array(obs), self.last_action, self.num_actions))[None]
        with torch.no_grad():
            logits, _, self.state = self.agent(x, self.state, torch.zeros(1, self.num_envs))
        logits = logits[0]
        if self.stay_rule:
            logits = rule_out_stay(logits, box_array(obs), self.stay_rule)
        if self.sample:
            action = torch.multinomial(torch.softmax(logits, -1), 1, generator=self.generator)[:, 0]
        else:
            action = logits.argmax(-1)
        action = action.numpy().astype(np.int64)
        self.last_action[:] = action
        return self.action_map(action, obs)


POLICIES: dict[str, Callable] = {
    "random": RandomPolicy,
    "servo": ServoPolicy,
    "explore": ExplorePolicy,
    "dqn": DQNPolicy,
    "memory": MemoryPolicy,
}


def policy_kwargs(
    name: str,
    then: str = "none",
    checkpoint: str = "",
    seed: int = 0,
    epsilon: float = 0.0,
    look_over: bool = False,
    first_turn: int = 0,
) -> dict:
    """The keyword arguments `make_policy` needs for `name` (and, for "explore", the policy it hands over to).
    `look_over` (scenes with occluders): the servo's or the exploration's sweep starts with LOOK_OVER, and the
    servo approaches from above. `first_turn`: the exploration's orbit first turns back after that many steps."""
    if first_turn and name != "explore":
        raise ValueError(f"first_turn is the exploration's (policy 'explore'), not policy {name!r}'s")
    if look_over and (name not in ("servo", "explore") or (name == "explore" and then == "servo")):
        raise ValueError(
            f"look_over is for policy 'servo' (which sweeps itself) or 'explore' handing over to dqn, random or none; "
            f"not policy {name!r} then {then!r}"
        )
    uses_dqn = name == "dqn" or (name == "explore" and then == "dqn")
    if uses_dqn and not checkpoint:
        raise ValueError(f"policy {name!r} (then {then!r}) needs a DQN checkpoint")
    kwargs = {"checkpoint": checkpoint, "epsilon": epsilon} if uses_dqn else {}
    if name == "memory":
        if not checkpoint:
            raise ValueError("policy 'memory' needs a checkpoint (e.g. agents/weights/search.pt)")
        kwargs = {"checkpoint": checkpoint}
    if name == "explore":
        kwargs["then"] = then
    if name in ("random", "explore", "dqn", "memory"):
        kwargs["seed"] = seed
    if look_over:
        kwargs["look_over"] = True
    if first_turn:
        kwargs["first_turn"] = first_turn
    return kwargs


def make_policy(name: str, env, **kwargs):
    if name not in POLICIES:
        raise ValueError(f"policy={name!r} is not one of: {', '.join(POLICIES)}")
    return POLICIES[name](env, **kwargs)
