"""`pd_ee_delta_pos` for the iiwa: Cartesian camera steps whose orientation follows the position.

The camera looks outward from the robot's vertical axis, pitched down by a fixed angle, horizon level
(docs/design.md §3, the "orbit" frame). With joints 3 and 5 held at zero and joint 7 fixed, joints 2, 4, 6 move in
one vertical plane that joint 1 turns about the base axis, so inverse kinematics is closed-form: joint 1 is
the camera's azimuth and joints 2, 4, 6 solve a planar three-link chain. It is exact, needs no iterations,
is batched in torch and runs unchanged on the GPU backend.

Steps are applied to the previous *target*, not the measured pose, so the lattice of positions is exact.
A step is refused (the arm holds, `refused` is set) when its solution breaks a joint limit, bends the
elbow past its safe branch (joint 4 > -0.3 rad), leaves the workspace bounds, or jumps a joint by more
than `max_joint_step` (the elbow-flip guard measured in docs/design.md §5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from gymnasium import spaces
from mani_skill.agents.controllers.pd_joint_pos import PDJointPosController, PDJointPosControllerConfig

from mani_active_vision.occluders import points_inside

# Kinematics of pybullet_data/kuka_iiwa/model.urdf (iiwa 14), read off its joint origins.
SHOULDER_HEIGHT = 0.36  # joint 2 above the base (0.1575 + 0.2025)
UPPER_ARM = 0.42  # joint 2 -> joint 4 (0.2045 + 0.2155)
FOREARM = 0.40  # joint 4 -> joint 6 (0.1845 + 0.2155)
WRIST_TO_EE = 0.081  # joint 6 -> link 7 origin (the end effector)
CAMERA_OFFSET = 0.06  # link 7 origin -> the wrist camera, along link 7's axis
JOINT_LIMITS = np.array(
    [2.96705972839, 2.09439510239, 2.96705972839, 2.09439510239, 2.96705972839, 2.09439510239, 3.05432619099]
)


def camera_forward(azimuth: torch.Tensor, pitch: float) -> torch.Tensor:
    """Unit viewing direction (N, 3) of a camera looking outward at `azimuth`, pitched down by `pitch` rad."""
    c = math.cos(pitch)
    return torch.stack([c * torch.cos(azimuth), c * torch.sin(azimuth), torch.full_like(azimuth, -math.sin(pitch))], -1)


def solve_ik(ee_pos: torch.Tensor, pitch: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint positions (N, 7) that put link 7 at `ee_pos` (N, 3) looking outward and down by `pitch`.

    Returns (qpos, ok): `ok` is False where no solution within the joint limits and safe elbow branch exists.
    """
    x, y, z = ee_pos.unbind(-1)
    radius = torch.sqrt(x * x + y * y)
    q1 = torch.atan2(y, x)
    phi3 = math.pi / 2 + pitch  # link 7's axis measured from vertical, in the arm's plane
    wrist_r = radius - WRIST_TO_EE * math.sin(phi3)
    wrist_z = z - WRIST_TO_EE * math.cos(phi3) - SHOULDER_HEIGHT
    dist_sq = wrist_r**2 + wrist_z**2
    cos_elbow = (dist_sq - UPPER_ARM**2 - FOREARM**2) / (2 * UPPER_ARM * FOREARM)
    reachable = cos_elbow.abs() <= 1.0
    elbow = torch.acos(cos_elbow.clamp(-1.0, 1.0))  # >= 0: the forearm bends outward (joint 4 negative)
    phi1 = torch.atan2(wrist_r, wrist_z) - torch.atan2(
        FOREARM * torch.sin(elbow), UPPER_ARM + FOREARM * torch.cos(elbow)
    )
    zero = torch.zeros_like(q1)
    qpos = torch.stack([q1, phi1, zero, -elbow, zero, phi3 - phi1 - elbow, zero], -1)
    limits = torch.as_tensor(JOINT_LIMITS, dtype=qpos.dtype, device=qpos.device) - 0.01
    ok = reachable & (qpos.abs() <= limits).all(-1)
    return qpos, ok


def forward_position(qpos: torch.Tensor) -> torch.Tensor:
    """Link 7's position (N, 3) for joint positions in the orbit family (joints 3, 5, 7 at zero)."""
    q1, q2, q4, q6 = qpos[..., 0], qpos[..., 1], qpos[..., 3], qpos[..., 5]
    phi1, phi2 = q2, q2 - q4
    phi3 = phi2 + q6
    radius = UPPER_ARM * torch.sin(phi1) + FOREARM * torch.sin(phi2) + WRIST_TO_EE * torch.sin(phi3)
    z = SHOULDER_HEIGHT + UPPER_ARM * torch.cos(phi1) + FOREARM * torch.cos(phi2) + WRIST_TO_EE * torch.cos(phi3)
    return torch.stack([radius * torch.cos(q1), radius * torch.sin(q1), z], -1)


def camera_end(ee_pos: torch.Tensor, pitch: float) -> torch.Tensor:
    """Joint 6, link 7 and the camera (N, 3, 3) for link 7 at `ee_pos` (N, 3) on the orbit rule."""
    forward = camera_forward(torch.atan2(ee_pos[:, 1], ee_pos[:, 0]), pitch)
    return torch.stack([ee_pos - WRIST_TO_EE * forward, ee_pos, ee_pos + CAMERA_OFFSET * forward], 1)


def arm_points(qpos: torch.Tensor, per_link: int = 8) -> torch.Tensor:
    """Points (N, 3 * per_link, 3) along the arm's centre line, shoulder -> elbow -> joint 6 -> link 7, for
    joint positions in the orbit family (for measuring where the whole arm goes, e.g. through a panel)."""
    q1, q2, q4, q6 = qpos[:, 0], qpos[:, 1], qpos[:, 3], qpos[:, 5]
    angles = torch.stack([q2, q2 - q4, q2 - q4 + q6], 1)  # each link's angle from vertical, in the arm's plane
    lengths = torch.tensor([UPPER_ARM, FOREARM, WRIST_TO_EE], dtype=qpos.dtype, device=qpos.device)
    steps = torch.stack([torch.sin(angles), torch.cos(angles)], -1) * lengths[:, None]  # (N, 3, 2): (r, z)
    joints = torch.cumsum(torch.cat([torch.tensor([0.0, SHOULDER_HEIGHT]).expand(len(qpos), 1, 2), steps], 1), 1)
    t = torch.linspace(0, 1, per_link, dtype=qpos.dtype, device=qpos.device)[None, None, :, None]
    rz = (joints[:, :-1, None] + t * (joints[:, 1:, None] - joints[:, :-1, None])).reshape(len(qpos), -1, 2)
    return torch.stack([rz[..., 0] * torch.cos(q1)[:, None], rz[..., 0] * torch.sin(q1)[:, None], rz[..., 1]], -1)


def step_allowed(
    new_pos: torch.Tensor, target_qpos: torch.Tensor, config, panels: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """The joint positions (N, 7) for commanded positions `new_pos` (N, 3), and whether a step there from
    joint targets `target_qpos` (N, 7) is accepted (else refused: docs/design.md §5). `config`: an
    `OrbitEEPosControllerConfig`; `panels` (N, K, 3): the task's occluders, which the camera end of the arm
    must keep clear of (`mani_active_vision.occluders`). Privileged planners ask it too, so that they judge
    steps as the arm does."""
    new_q, ok = solve_ik(new_pos, config.pitch)
    if panels is not None and panels.shape[1]:
        ok &= ~points_inside(camera_end(new_pos, config.pitch), panels).any(-1)
    x, y, z = new_pos.unbind(-1)
    radius = torch.sqrt(x * x + y * y)
    ok &= (z >= config.min_height) & (z <= config.max_height)
    ok &= (radius >= config.min_radius) & (radius <= config.max_radius)
    ok &= new_q[:, 3] <= config.max_elbow
    ok &= (new_q - target_qpos).abs().amax(-1) <= config.max_joint_step
    return new_q, ok


class OrbitEEPosController(PDJointPosController):
    """Delta-position control of link 7 with the orientation given by the orbit rule (see module doc)."""

    config: OrbitEEPosControllerConfig

    def _initialize_action_space(self):
        bound = np.full(3, self.config.max_step, dtype=np.float32)
        self.single_action_space = spaces.Box(-bound, bound, dtype=np.float32)

    def reset(self):
        """Called by ManiSkill after every reset, with all envs in the reset mask even on a partial reset:
        only a single env (or the first call) starts from the measured joint positions here. Batched
        tasks call `start_episode` for the envs they reset."""
        if getattr(self, "target_pos", None) is None or self.scene.num_envs == 1:
            self.start_episode(torch.arange(self.scene.num_envs, device=self.device), self.qpos)

    def start_episode(self, env_idx: torch.Tensor, qpos: torch.Tensor):
        """Start episodes of envs `env_idx` whose arms were set to `qpos` (b, 7): hold there; the first step
        starts from the matching rule position, or from the entry point when `qpos` is off the rule."""
        n = self.scene.num_envs
        if getattr(self, "target_pos", None) is None:
            self.target_pos = torch.zeros(n, 3, device=self.device)
            self._target_qpos = torch.zeros(n, 7, device=self.device)
            self._drive_qpos = torch.zeros(n, 7, device=self.device)
            self.refused = torch.zeros(n, dtype=torch.bool, device=self.device)
            self.refused_count = torch.zeros(n, dtype=torch.int32, device=self.device)
        qpos = qpos.to(self.device, torch.float32)
        pos = forward_position(qpos)
        rule_q, ok = solve_ik(pos, self.config.pitch)
        on_rule = (ok & ((rule_q - qpos).abs().amax(-1) < 1e-3))[:, None]
        entry = torch.as_tensor(self.config.entry_pos, dtype=pos.dtype, device=self.device).expand_as(pos)
        entry_q, _ = solve_ik(entry, self.config.pitch)
        self.target_pos[env_idx] = torch.where(on_rule, pos, entry)
        self._target_qpos[env_idx] = torch.where(on_rule, qpos, entry_q)
        self._drive_qpos[env_idx] = qpos
        self.refused[env_idx] = False
        self.refused_count[env_idx] = 0
        self.set_drive_targets(self._drive_qpos)

    def set_action(self, action):
        action = self._preprocess_action(action).clamp(-self.config.max_step, self.config.max_step)
        new_pos = self.target_pos + action
        new_q, ok = step_allowed(new_pos, self._target_qpos, self.config, getattr(self, "panels", None))
        self.refused = ~ok
        self.refused_count += self.refused.to(torch.int32)
        self.target_pos = torch.where(ok[:, None], new_pos, self.target_pos)
        self._target_qpos = torch.where(ok[:, None], new_q, self._target_qpos)
        # An env whose arm is off the rule (the sky start) holds there until its first accepted step.
        self._drive_qpos = torch.where(ok[:, None], self._target_qpos, self._drive_qpos)
        self.set_drive_targets(self._drive_qpos)

    def before_simulation_step(self):
        pass

    def get_state(self) -> dict:
        return {"target_pos": self.target_pos, "target_qpos": self._target_qpos, "drive_qpos": self._drive_qpos}

    def set_state(self, state: dict):
        self.target_pos = state["target_pos"].clone()
        self._target_qpos = state["target_qpos"].clone()
        self._drive_qpos = state["drive_qpos"].clone()
        self.set_drive_targets(self._drive_qpos)


@dataclass
class OrbitEEPosControllerConfig(PDJointPosControllerConfig):
    pitch: float = math.radians(60)
    """camera pitch below the horizon (rad); 60° measured best for zooming in (docs/design.md §3)"""
    max_step: float = 0.1
    """largest commanded move per axis and step (m)"""
    entry_pos: tuple = (0.30, 0.0, 0.90)
    """where the first step starts from when the arm is off the rule (the 'sky' start)"""
    min_height: float = 0.10
    max_height: float = 1.05
    min_radius: float = 0.10
    max_radius: float = 0.85
    max_elbow: float = -0.3
    """joint 4 stays at or below this (rad): keeps the elbow off its straight singularity"""
    max_joint_step: float = 0.6
    """a step that moves any joint target more than this (rad) is refused (elbow-flip guard)"""
    normalize_action: bool = False
    controller_cls = OrbitEEPosController
