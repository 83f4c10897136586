"""The paper's six discrete camera moves over `pd_ee_delta_pos` (docs/design.md §3, the orbit frame), and an
optional seventh action, `stay`."""

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


def action_names(stay_action: bool = False) -> tuple[str, ...]:
    """The actions' names in index order: the six directions, then `stay` if enabled (so the six keep
    their indices either way)."""
    return (*DIRECTIONS, STAY) if stay_action else DIRECTIONS


def direction_deltas(pos: torch.Tensor, step: float, pitch: float, names: tuple[str, ...] = DIRECTIONS) -> torch.Tensor:
    """The Cartesian steps (N, len(names), 3) of the named actions from commanded positions `pos` (N, 3).

    Orbit steps are arcs of length `step` at the position's radius and height, so that a left step and a
    right step return exactly; forward/backward follow the viewing axis at the position's azimuth."""
    radius = torch.linalg.norm(pos[:, :2], dim=-1).clamp(min=1e-6)
    azimuth = torch.atan2(pos[:, 1], pos[:, 0])

    def orbit(turn):  # left = counter-clockwise seen from above
        return (
            torch.stack([radius * torch.cos(azimuth + turn), radius * torch.sin(azimuth + turn), pos[:, 2]], -1) - pos
        )

    forward = step * camera_forward(azimuth, pitch)
    up = torch.zeros_like(pos)
    up[:, 2] = step
    moves = dict(
        left=orbit(step / radius),
        right=orbit(-step / radius),
        forward=forward,
        backward=-forward,
        up=up,
        down=-up,
        stay=torch.zeros_like(pos),
    )
    unknown = [n for n in names if n not in moves]
    if unknown:
        raise ValueError(f"unknown action names {unknown}: valid are {tuple(moves)}")
    return torch.stack([moves[name] for name in names], 1)


class DiscreteDirections(gym.ActionWrapper):
    """`Discrete(6)` actions (`MultiDiscrete` for batched envs), indices into `DIRECTIONS`; with
    `stay_action`, `Discrete(7)`: index 6 is `stay` (`action_names`).

    Each direction is turned into the Cartesian step from the controller's current target, so that orbit
    steps stay on their circle exactly. The step length is the task's `step_size`.
    """

    def __init__(self, env: gym.Env, stay_action: bool = False):
        super().__init__(env)
        base = env.unwrapped
        if base.control_mode != "pd_ee_delta_pos":
            raise ValueError(f"DiscreteDirections needs control_mode='pd_ee_delta_pos', got {base.control_mode!r}")
        self.num_envs = base.num_envs
        self._batched = len(env.action_space.shape) == 2
        self.names = action_names(stay_action)
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
        idx = self._indices(action).to(base.device)
        deltas = direction_deltas(controller.target_pos, base.step_size, controller.config.pitch, self.names)
        delta = deltas[torch.arange(len(idx)), idx]
        if self._batched:
            return delta
        return delta[0].cpu().numpy().astype(np.float32)
