"""The paper's environment re-implemented in PyBullet, as the speed reference for `baselines/benchmark.py`.

The setup of "Active Vision for Robotics" (2018): the KUKA iiwa of `pybullet_data` (`kuka_iiwa/model.urdf`)
on a plane, objects from `pybullet_data/random_urdfs` on the floor, a wrist camera rendered with
`getCameraImage` and PyBullet's TinyRenderer (rgb + segmentation), six discrete camera moves turned into
joint targets by PyBullet's inverse kinematics, reward = the target's share of the image. To make the
comparison fair it does the same work per step as ActiveVisionFind-v0: 20 Hz control over 100 Hz physics
(5 physics steps per action), the same camera (70° fov, near 0.01 m, far 10 m, square image) and orbit
frame (looking outward from the robot's axis, 60° down), five objects of 7-10 cm at 0.70-0.90 m, and new
objects on every reset. Speed only: no refusals, success test or target image.

    .venv/bin/python baselines/pybullet_reference.py --resolution 128
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np
import pybullet
import pybullet_data
import tyro
from pybullet_utils.bullet_client import BulletClient

from mani_active_vision.directions import DIRECTIONS

EE_LINK = 6  # lbr_iiwa_link_7: the parent link of joint 7
PITCH = math.radians(60)
START_POS = (0.30, 0.0, 0.90)
CAMERA_OFFSET = 0.06  # m along link 7's axis, as on the ManiSkill robot
TRAIN_MODELS = range(0, 800)


def orbit_orientation(pos: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of link 7 looking outward from the base axis at `pos`, `PITCH` down, horizon level:
    link 7's z is the viewing axis and its -x points up in the image (as on the ManiSkill robot)."""
    azimuth = math.atan2(pos[1], pos[0])
    forward = np.array([math.cos(PITCH) * math.cos(azimuth), math.cos(PITCH) * math.sin(azimuth), -math.sin(PITCH)])
    image_up = np.array([0.0, 0.0, 1.0]) - forward[2] * forward
    image_up /= np.linalg.norm(image_up)
    x = -image_up
    rotation = np.stack([x, np.cross(forward, x), forward], 1)  # columns: link 7's axes in the world
    return _quaternion_from_matrix(rotation)


def _quaternion_from_matrix(m: np.ndarray) -> np.ndarray:
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    return np.array([x, y, z, w])


class PyBulletReference:
    """One env: `reset(seed)` -> obs; `step(direction index)` -> (obs, reward); obs = dict(rgb, segmentation)."""

    num_objects = 5
    sim_freq, control_freq = 100, 20
    step_size = 0.05

    def __init__(self, resolution: int = 128, num_objects: int = 5):
        self.resolution = resolution
        self.num_objects = num_objects
        self.client = BulletClient(connection_mode=pybullet.DIRECT)
        self.client.setAdditionalSearchPath(pybullet_data.getDataPath())
        self.client.setGravity(0, 0, -9.81)
        self.client.setTimeStep(1 / self.sim_freq)
        self.client.loadURDF("plane.urdf")
        self.robot = self.client.loadURDF("kuka_iiwa/model.urdf", useFixedBase=True)
        self.joints = list(range(self.client.getNumJoints(self.robot)))
        self.projection = self.client.computeProjectionMatrixFOV(70, 1.0, 0.01, 10.0)
        self.objects: list[int] = []
        self._extents: dict[int, tuple] = {}
        self.rng = np.random.default_rng()

    def reset(self, seed: int | None = None) -> dict:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        for body in self.objects:
            self.client.removeBody(body)
        self.objects = [
            self._load_object(model, placed)
            for model, placed in zip(self.rng.choice(TRAIN_MODELS, self.num_objects, replace=False), self._layout())
        ]
        self.target_pos = np.array(START_POS)
        for joint, q in zip(self.joints, self._ik(self.target_pos, iterations=50)):
            self.client.resetJointState(self.robot, joint, q)
        self._drive(self.target_pos)
        return self._observe()

    def step(self, action: int) -> tuple[dict, float]:
        new_pos = self.target_pos + self._delta(action)
        radius, azimuth = math.hypot(new_pos[0], new_pos[1]), math.atan2(new_pos[1], new_pos[0])
        if 0.10 <= new_pos[2] <= 1.05 and 0.10 <= radius <= 0.85 and abs(azimuth) <= 2.9:  # else refused, as ours
            self.target_pos = new_pos  # (PyBullet's IK ignores joint limits: joint 1 stops at ±2.97 rad)
        self._drive(self.target_pos)
        for _ in range(self.sim_freq // self.control_freq):
            self.client.stepSimulation()
        obs = self._observe()
        reward = float((obs["segmentation"] == self.objects[0]).mean())  # the target's share of the image
        return obs, reward

    def close(self):
        self.client.disconnect()

    def _layout(self) -> list[np.ndarray]:
        placed = []
        while len(placed) < self.num_objects:
            r, az = self.rng.uniform(0.70, 0.90), self.rng.uniform(-math.radians(155), math.radians(155))
            xy = np.array([r * math.cos(az), r * math.sin(az)])
            if all(np.linalg.norm(xy - p) >= 0.15 for p in placed):
                placed.append(xy)
        return placed

    def _load_object(self, model: int, xy: np.ndarray) -> int:
        urdf = os.path.join("random_urdfs", f"{model:03d}", f"{model:03d}.urdf")
        if model not in self._extents:  # measured once at scale 1 (URDF scale is only set at load time)
            body = self.client.loadURDF(urdf)
            self._extents[model] = tuple(np.array(v) for v in self.client.getAABB(body))
            self.client.removeBody(body)
        low, high = self._extents[model]
        scale = self.rng.uniform(0.07, 0.10) / max(high - low)
        yaw = self.client.getQuaternionFromEuler([0, 0, self.rng.uniform(0, 2 * math.pi)])
        return self.client.loadURDF(urdf, [xy[0], xy[1], -low[2] * scale + 0.001], yaw, globalScaling=scale)

    def _delta(self, action: int) -> np.ndarray:
        direction = DIRECTIONS[action]
        x, y, z = self.target_pos
        radius, azimuth = math.hypot(x, y), math.atan2(y, x)
        if direction in ("left", "right"):
            turn = self.step_size / radius * (1 if direction == "left" else -1)
            return np.array([radius * math.cos(azimuth + turn) - x, radius * math.sin(azimuth + turn) - y, 0.0])
        forward = np.array([math.cos(PITCH) * math.cos(azimuth), math.cos(PITCH) * math.sin(azimuth), -math.sin(PITCH)])
        return (
            self.step_size
            * dict(forward=forward, backward=-forward, up=np.array([0, 0, 1.0]), down=np.array([0, 0, -1.0]))[direction]
        )

    def _ik(self, pos: np.ndarray, iterations: int = 20) -> list[float]:
        return self.client.calculateInverseKinematics(
            self.robot, EE_LINK, pos, orbit_orientation(pos), maxNumIterations=iterations
        )

    def _drive(self, pos: np.ndarray):
        self.client.setJointMotorControlArray(
            self.robot,
            self.joints,
            pybullet.POSITION_CONTROL,
            targetPositions=self._ik(pos),
            forces=[1000.0] * len(self.joints),
            positionGains=[0.5] * len(self.joints),
        )

    def _observe(self) -> dict:
        link = self.client.getLinkState(self.robot, EE_LINK, computeForwardKinematics=True)
        rotation = np.array(self.client.getMatrixFromQuaternion(link[5])).reshape(3, 3)
        eye = np.array(link[4]) + CAMERA_OFFSET * rotation[:, 2]
        view = self.client.computeViewMatrix(eye, eye + rotation[:, 2], -rotation[:, 0])
        _, _, rgba, _, segmentation = self.client.getCameraImage(
            self.resolution, self.resolution, view, self.projection, renderer=pybullet.ER_TINY_RENDERER
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(self.resolution, self.resolution, 4)
        segmentation = np.asarray(segmentation, dtype=np.int32).reshape(self.resolution, self.resolution)
        return dict(rgb=rgba[..., :3], segmentation=segmentation)


def steps_per_second(resolution: int, steps: int, episode_steps: int = 100, seed: int = 0) -> float:
    """Random-direction steps per second of one reference env (new objects every `episode_steps`)."""
    env = PyBulletReference(resolution)
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).integers(0, len(DIRECTIONS), size=steps)
    start = time.perf_counter()
    for i, action in enumerate(actions):
        env.step(int(action))
        if (i + 1) % episode_steps == 0:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed


@dataclass
class Args:
    resolution: int = 128
    """camera image side (pixels)"""
    steps: int = 300
    """steps to time"""
    seed: int = 0


if __name__ == "__main__":
    args = tyro.cli(Args)
    print(
        f"PyBullet reference, {args.resolution}² rgb+segmentation: {steps_per_second(args.resolution, args.steps, seed=args.seed):.0f} steps/s"
    )
