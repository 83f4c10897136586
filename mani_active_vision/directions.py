"""The paper's six discrete camera moves over `pd_ee_delta_pos` (docs/design.md §3, the orbit frame), an
optional seventh action, `stay`, and optionally the six moves again at a finer step."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from mani_active_vision.robots.orbit_controller import camera_forward

DIRECTIONS = ("left", "right", "forward", "backward", "up", "down")
"""left/right: a `step_size` arc around the robot's vertical axis (constant radius and height; the view
pans left/right); forward/backward: along the camera's viewing axis (zoom in/out); up/down: vertical."""
LEFT = DIRECTIONS.index("left")
STAY = "stay"
"""The optional seventh action (not the paper's): a zero step, so that an agent can hold a view. From the
`sky` start it goes to the search pose like any first step (docs/design.md §3)."""


FINE = tuple(f"{name}_fine" for name in DIRECTIONS)
"""The optional fine moves (not the paper's): the six directions at the env's `fine_step_size`, so that the
policy that takes over from the exploration can land on a view in success that the full step passes over
(docs/control.md §11)."""


FINE_NEAR_CENTRE = 0.3
"""How far (a fraction of the image's side, in x and in y) the target's box centre may lie from the image centre
for a policy to take the fine moves there (`DiscreteDirections.fine_near_centre`; success needs 0.15). The
default is the one every agent learned with; the shipped DQNs are deployed at `envs.DQN_FINE_NEAR_CENTRE`
(docs/control.md §11, §18)."""

FINE_AREA = (0.02, 0.25)
"""The share of the image the target's box covers where a policy takes the fine moves (with its centre near the
image centre, `FINE_NEAR_CENTRE`): from `DiscreteDirections.fine_from_area` (default the first number, the one
every agent learned with; success needs the target's own pixels to cover 5%) up to the second. Farther out a full
step does not pass over a view in success; a larger box is a target pushed too close (docs/control.md §11, §32)."""


def action_names(stay_action: bool = False, fine_actions: bool = False) -> tuple[str, ...]:
    """The actions' names in index order: the six directions, then `stay` if enabled, then the six fine moves
    if enabled (so the six, and `stay`, keep their indices either way)."""
    return (*DIRECTIONS, *((STAY,) if stay_action else ()), *(FINE if fine_actions else ()))


def action_names_for(count: int) -> tuple[str, ...]:
    """The action set an env with `count` actions takes: 6 directions, 7 with `stay`, 12 with the fine moves,
    13 with both."""
    sets = {len(action_names(stay, fine)): action_names(stay, fine) for stay in (False, True) for fine in (False, True)}
    if count not in sets:
        raise ValueError(f"no action set has {count} actions: valid counts are {sorted(sets)}")
    return sets[count]


def action_count(space: gym.Space) -> int:
    """How many discrete actions a `Discrete` space, or a batched env's `MultiDiscrete` one, offers."""
    if isinstance(space, gym.spaces.Discrete):
        return int(space.n)
    if isinstance(space, gym.spaces.MultiDiscrete):
        return int(space.nvec.reshape(-1)[0])
    raise TypeError(f"{space} is not a discrete action space: wrap the env in DiscreteDirections")


def direction_deltas(
    pos: torch.Tensor, step: float, pitch: float, names: tuple[str, ...] = DIRECTIONS, fine_step: float = 0.0
) -> torch.Tensor:
    """The Cartesian steps (N, len(names), 3) of the named actions from commanded positions `pos` (N, 3); the
    fine moves (`FINE`) are `fine_step` long.

    Orbit steps are arcs of length `step` at the position's radius and height, so that a left step and a
    right step return exactly; forward/backward follow the viewing axis at the position's azimuth. Only the
    named moves are computed: an env's step asks for one (its small tensor operations are most of the cost)."""
    unknown = [n for n in names if n not in (*DIRECTIONS, STAY, *FINE)]
    if unknown:
        raise ValueError(f"unknown action names {unknown}: valid are {(*DIRECTIONS, STAY, *FINE)}")
    if any(name in FINE for name in names) and fine_step <= 0:
        raise ValueError(f"the fine moves {FINE} need fine_step > 0, got {fine_step}")
    frame = _Frame(pos, pitch)
    moves = [frame.move(name[: -len("_fine")], fine_step) if name in FINE else frame.move(name, step) for name in names]
    return torch.stack(moves, 1)


class _Frame:
    """The orbit frame at commanded positions `pos` (N, 3): each direction's (and `stay`'s) Cartesian step."""

    def __init__(self, pos: torch.Tensor, pitch: float):
        self.pos, self.pitch = pos, pitch
        self.radius = torch.linalg.norm(pos[:, :2], dim=-1).clamp(min=1e-6)
        self.azimuth = torch.atan2(pos[:, 1], pos[:, 0])

    def move(self, name: str, step: float) -> torch.Tensor:
        """The step (N, 3) of direction `name` (or `stay`), `step` long."""
        pos = self.pos
        if name in ("left", "right"):  # left = counter-clockwise seen from above
            turn = self.azimuth + (step if name == "left" else -step) / self.radius
            return torch.stack([self.radius * torch.cos(turn), self.radius * torch.sin(turn), pos[:, 2]], -1) - pos
        if name in ("forward", "backward"):
            forward = step * camera_forward(self.azimuth, self.pitch)
            return forward if name == "forward" else -forward
        up = torch.zeros_like(pos)
        if name == STAY:
            return up
        up[:, 2] = step
        return up if name == "up" else -up


def check_direction_options(
    step_size: float,
    fine_step: float,
    fine_near_centre: float,
    fine_from_area: float,
    back_when_close: float,
    explore_resumes_after: int,
    fine_step_name: str = "fine_step",
) -> None:
    """A `ValueError` naming the bad value and the valid range for `DiscreteDirections`' options; `EnvConfig` checks
    its own with the same rules (its fine step is called `fine_step_size`: `fine_step_name`)."""
    if not 0 <= fine_step < step_size:
        raise ValueError(f"{fine_step_name}={fine_step!r} must be in [0, step_size={step_size}) (0: no fine moves)")
    if not 0 < fine_near_centre <= 0.5:
        raise ValueError(f"fine_near_centre={fine_near_centre!r} must be in (0, 0.5]: a distance from the image centre")
    if not 0 < fine_from_area < FINE_AREA[1]:
        raise ValueError(
            f"fine_from_area={fine_from_area!r} must be in (0, {FINE_AREA[1]}): a share of the image covered by the box"
        )
    if not 0 <= back_when_close <= 1:
        raise ValueError(f"back_when_close={back_when_close!r} must be in [0, 1] (0: off): a share of the image")
    if not (isinstance(explore_resumes_after, int) and explore_resumes_after >= 0):
        raise ValueError(f"explore_resumes_after={explore_resumes_after!r} must be an integer of at least 0 (0: never)")


class DiscreteDirections(gym.ActionWrapper):
    """`Discrete(6)` actions (`MultiDiscrete` for batched envs), indices into `DIRECTIONS`; with
    `stay_action`, `Discrete(7)`: index 6 is `stay`; with `fine_step` > 0 the six `FINE` moves follow
    (`action_names`).

    Each direction is turned into the Cartesian step from the controller's current target, so that orbit
    steps stay on their circle exactly. The step length is the task's `step_size` (`fine_step` for `FINE`).
    `fine_near_centre` and `fine_from_area` are where policies take the fine moves (`agents.policies.near_target`):
    they are kept here, with the moves, so that a policy reads them from the env it acts in
    (`agents.policies.fine_zone`), as it reads `back_when_close` (`agents.policies.too_close`),
    `stay_needs_success` (`agents.policies.stay_rule`), `explore_resumes_after` (`agents.policies.ExplorePolicy`) and
    `sweep_retraces` (`agents.policies.sweep_moves`).
    """

    def __init__(
        self,
        env: gym.Env,
        stay_action: bool = False,
        fine_step: float = 0.0,
        fine_near_centre: float = FINE_NEAR_CENTRE,
        fine_from_area: float = FINE_AREA[0],
        back_when_close: float = 0.0,
        stay_needs_success: bool = False,
        explore_resumes_after: int = 0,
        sweep_retraces: bool = False,
    ):
        super().__init__(env)
        base = env.unwrapped
        if base.control_mode != "pd_ee_delta_pos":
            raise ValueError(f"DiscreteDirections needs control_mode='pd_ee_delta_pos', got {base.control_mode!r}")
        self.num_envs = base.num_envs
        self._batched = len(env.action_space.shape) == 2
        check_direction_options(
            base.step_size, fine_step, fine_near_centre, fine_from_area, back_when_close, explore_resumes_after
        )
        self.fine_step, self.fine_near_centre, self.fine_from_area = fine_step, fine_near_centre, fine_from_area
        self.back_when_close = back_when_close
        self.stay_needs_success, self.explore_resumes_after = stay_needs_success, explore_resumes_after
        self.sweep_retraces = bool(sweep_retraces)
        self.names = action_names(stay_action, fine_step > 0)
        n = len(self.names)
        self.action_space = gym.spaces.MultiDiscrete([n] * self.num_envs) if self._batched else gym.spaces.Discrete(n)

    def _indices(self, action) -> torch.Tensor:
        array = action.cpu().numpy() if isinstance(action, torch.Tensor) else np.asarray(action)
        if not np.issubdtype(array.dtype, np.integer):
            raise TypeError(
                f"action must be an integer index into DIRECTIONS (+ stay if enabled) {self.names}, got dtype {array.dtype}"
            )
        shape = (self.num_envs,) if self._batched else ()
        if array.shape != shape and not (not self._batched and array.shape == (1,)):
            raise ValueError(f"action must have shape {shape}, got {array.shape}")
        if array.min() < 0 or array.max() >= len(self.names):
            raise ValueError(f"action {array.tolist()} out of range: valid are 0..{len(self.names) - 1} = {self.names}")
        return torch.as_tensor(array.reshape(-1), dtype=torch.long)

    def action(self, action):
        base = self.env.unwrapped
        controller = base.agent.controller
        used, column = torch.unique(self._indices(action), return_inverse=True)  # only the moves asked for
        names = tuple(self.names[i] for i in used.tolist())
        deltas = direction_deltas(controller.target_pos, base.step_size, controller.config.pitch, names, self.fine_step)
        delta = deltas[torch.arange(len(column), device=base.device), column.to(base.device)]
        if self._batched:
            return delta
        return delta[0].cpu().numpy().astype(np.float32)
