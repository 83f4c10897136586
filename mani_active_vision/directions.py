"""The paper's six discrete camera moves over `pd_ee_delta_pos` (docs/design.md §3, the orbit frame)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from mani_active_vision.robots.orbit_controller import camera_forward

DIRECTIONS = ("left", "right", "forward", "backward", "up", "down")
"""left/right: a `step_size` arc around the robot's vertical axis (constant radius and height; the view
pans left/right); forward/backward: along the camera's viewing axis (zoom in/out); up/down: vertical."""
LEFT = DIRECTIONS.index("left")


class DiscreteDirections(gym.ActionWrapper):
    """`Discrete(6)` actions (`MultiDiscrete` for batched envs), indices into `DIRECTIONS`.

    Each direction is turned into the Cartesian step from the controller's current target, so that orbit
    steps stay on their circle exactly. The step length is the task's `step_size`.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        base = env.unwrapped
        if base.control_mode != "pd_ee_delta_pos":
            raise ValueError(f"DiscreteDirections needs control_mode='pd_ee_delta_pos', got {base.control_mode!r}")
        self.num_envs = base.num_envs
        self._batched = len(env.action_space.shape) == 2
        n = len(DIRECTIONS)
        self.action_space = gym.spaces.MultiDiscrete([n] * self.num_envs) if self._batched else gym.spaces.Discrete(n)

    def _indices(self, action) -> torch.Tensor:
        array = action.cpu().numpy() if isinstance(action, torch.Tensor) else np.asarray(action)
        if not np.issubdtype(array.dtype, np.integer):
            raise TypeError(f"action must be an integer index into DIRECTIONS {DIRECTIONS}, got dtype {array.dtype}")
        shape = (self.num_envs,) if self._batched else ()
        if array.shape != shape and not (not self._batched and array.shape == (1,)):
            raise ValueError(f"action must have shape {shape}, got {array.shape}")
        if array.min() < 0 or array.max() >= len(DIRECTIONS):
            raise ValueError(f"action {array.tolist()} out of range: valid are 0..{len(DIRECTIONS) - 1} = {DIRECTIONS}")
        return torch.as_tensor(array.reshape(-1), dtype=torch.long)

    def action(self, action):
        base = self.env.unwrapped
        controller = base.agent.controller
        idx = self._indices(action).to(base.device)
        pos = controller.target_pos
        step = base.step_size
        radius = torch.linalg.norm(pos[:, :2], dim=-1).clamp(min=1e-6)
        azimuth = torch.atan2(pos[:, 1], pos[:, 0])
        turn = torch.where(idx == LEFT, step / radius, -step / radius)  # left = counter-clockwise seen from above
        orbit = (
            torch.stack([radius * torch.cos(azimuth + turn), radius * torch.sin(azimuth + turn), pos[:, 2]], -1) - pos
        )
        forward = step * camera_forward(azimuth, controller.config.pitch)
        up = torch.zeros_like(pos)
        up[:, 2] = step
        moves = dict(left=orbit, right=orbit, forward=forward, backward=-forward, up=up, down=-up)
        delta = torch.stack([moves[name] for name in DIRECTIONS], 1)[torch.arange(len(idx)), idx]
        if self._batched:
            return delta
        return delta[0].cpu().numpy().astype(np.float32)
