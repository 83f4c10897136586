"""The KUKA iiwa 14 of the paper, from the `pybullet` wheel's data, with a camera on its wrist."""

from __future__ import annotations

import math
import os

import numpy as np
import pybullet_data
import sapien
import torch
from mani_skill.agents.base_agent import BaseAgent, Keyframe
from mani_skill.agents.registration import register_agent
from mani_skill.sensors.camera import CameraConfig

from ..wrist_shader import wrist_shader_config
from .orbit_controller import CAMERA_OFFSET, OrbitEEPosControllerConfig, solve_ik

ARM_JOINTS = [f"lbr_iiwa_joint_{i}" for i in range(1, 8)]
EE_LINK = "lbr_iiwa_link_7"
SEARCH_POS = (0.30, 0.0, 0.90)
"""Search pose: link 7 at radius 0.30 m, height 0.90 m, looking outward; sees the floor ~0.25 to ~2.2 m away."""
CAMERA_PITCH = math.radians(60)


def _rule_qpos(ee_pos) -> np.ndarray:
    qpos, ok = solve_ik(torch.tensor([ee_pos], dtype=torch.float64), CAMERA_PITCH)
    assert bool(ok[0]), ee_pos
    return qpos[0].numpy()


@register_agent()
class IiwaWristCam(BaseAgent):
    """KUKA LBR iiwa 14 R820 with a wrist camera `hand_camera` looking along link 7's axis.

    Control mode `pd_ee_delta_pos`: camera steps in the orbit frame (see `orbit_controller`).
    Keyframes: `sky` (qpos = 0, the paper's start: pointing straight up) and `search`.
    """

    uid = "iiwa_wristcam"
    urdf_path = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa", "model.urdf")
    fix_root_link = True
    # The hulls of link 5 and link 7 touch at rest (docs/design.md §4): self-collision would push the arm apart.
    disable_self_collisions = True

    keyframes = dict(
        sky=Keyframe(pose=sapien.Pose(), qpos=np.zeros(7)),
        search=Keyframe(pose=sapien.Pose(), qpos=_rule_qpos(SEARCH_POS)),
    )

    # Stiff drives: 1e3/1e2 moved only ~40% of a 5 cm step per control step; 1e5/1e3 with force limit
    # 1000 moves all of it without joint 2 lagging (docs/design.md §4).
    stiffness = 1e5
    damping = 1e3
    force_limit = 1000

    @property
    def _controller_configs(self):
        return dict(
            pd_ee_delta_pos=OrbitEEPosControllerConfig(
                ARM_JOINTS,
                lower=None,
                upper=None,
                stiffness=self.stiffness,
                damping=self.damping,
                force_limit=self.force_limit,
                pitch=CAMERA_PITCH,
                entry_pos=SEARCH_POS,
            )
        )

    @property
    def _sensor_configs(self):
        # SAPIEN cameras look along +x with +z up; link 7 looks along its +z, and with joint 7 at zero its
        # -x points up in the image: a -90° turn about y maps one onto the other (horizon level).
        return [
            CameraConfig(
                uid="hand_camera",
                pose=sapien.Pose(p=[0, 0, CAMERA_OFFSET], q=[math.sqrt(0.5), 0, -math.sqrt(0.5), 0]),
                width=128,
                height=128,
                fov=math.radians(70),
                near=0.01,
                far=10.0,
                mount=self.robot.links_map[EE_LINK],
                shader_config=wrist_shader_config(),  # the same images as ManiSkill's `minimal`, in one pass
            )
        ]

    def _after_init(self):
        self.ee_link = self.robot.links_map[EE_LINK]

    @property
    def ee_pose(self):
        return self.ee_link.pose
