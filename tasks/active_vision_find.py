"""ActiveVisionFind-v0: find an object seen once, and zoom in on it, with a camera on the arm's wrist.

**Task Description:**
A KUKA iiwa with a wrist camera (`hand_camera`) must bring a target object into view, centred and large.
The target is shown once per episode as a zoomed, centred image of it alone (`obs["extra"]["target_image"]`,
non-target pixels grey), from the side the robot sees it (the wrist camera's elevation and line of sight).
The camera's orientation follows its position (it looks outward from the robot's vertical axis, 60° down,
horizon level), so `pd_ee_delta_pos` moves it around the robot (see
`mani_active_vision.DiscreteDirections` for the paper's six discrete directions).

**Randomizations:**
- `num_objects` objects from `object_set` (train / unseen / primitives), largest extent 7-10 cm; slot 0
  is the target. Some distractors take the target's colour, some its shape (in another colour), so colour
  alone does not solve segmentation and no distractor is an identical twin of the target. A new draw on every reset when `num_envs == 1` (ManiSkill's reconfiguration).
- `placement="random"`: objects 0.70-0.90 m from the base, within ±155° of azimuth (behind the robot is a
  wedge the camera cannot centre), at least 0.15 m apart, random yaw. `"fixed"`: the same scene every
  episode (the paper's first experiment).
- The arm starts at `start_pose`: `"sky"` (qpos = 0, pointing up, as in the paper) or `"search"`.
- `occluders=k` (default 0): k upright panels, 50 cm tall, each between the robot's base and object i < k
  (object 0 is the target) at a random sideways offset, never within 2 cm of an object or another panel:
  from the search height they hide all, part or none of that object (`mani_active_vision.occluders`).

**Success Conditions:**
The target is fully in view (no target pixel on the image border, and at least `min_visible_fraction` of
its pixels not hidden behind an occluder: `info["target_visible_fraction"]`), its centroid within
`success_center_tol` of the image width from the centre, and it covers at least `success_fraction` of
the image. Defaults 0.05 and 0.15 (≈19 px at 128²): a privileged planner
(`baselines/success_reachability.py`, 40 random placements) met them for 93% of placements, against 90%
at 0.06, 85% at 0.08 and 80% at 0.10; a tighter tolerance is often unreachable since one orbit step moves
a close object 25-45 px.

`render_free=True` (with a state obs_mode, no occluders) takes the target's mask from its convex hull projected
into the wrist camera instead of rendering it (`mani_active_vision.projection`: an approximation, measured
in docs/speed.md), so that a step renders nothing.

Reward: `dense` = target_fraction (the paper's); `normalized_dense` = target_fraction / success_fraction,
capped at 1; `sparse` = success. Success does not end the episode unless `terminate_on_success`.
"""

from __future__ import annotations

import gc
import math
import types

import gymnasium as gym
import numpy as np
import sapien
import torch
from mani_skill.envs import sapien_env
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Actor, Pose

from mani_active_vision.boxes import target_stats
from mani_active_vision.brdf_lut import supply_brdf_lut
from mani_active_vision.culling import ViewCuller
from mani_active_vision.floor import build_floor
from mani_active_vision.objects import OBJECT_SETS, OBJECT_SIZE, PALETTE, build_object, hull_points, object_set
from mani_active_vision.occluders import MIN_VISIBLE_FRACTION, build_panel, place_panels
from mani_active_vision.projection import extrinsic_cv, hull_mask, rotation_matrix
from mani_active_vision.robots.iiwa import CAMERA_PITCH, SEARCH_POS, IiwaWristCam
from mani_active_vision.robots.orbit_controller import camera_end

PLACEMENTS = ("random", "fixed")
START_POSES = ("sky", "search")
OBS_MODES = ("rgb+segmentation", "rgb", "state", "state_dict", "none")
REWARD_MODES = ("dense", "normalized_dense", "sparse", "none")
CONTROL_MODES = ("pd_ee_delta_pos",)
_NO_FORCED_COLLECTION = types.SimpleNamespace(collect=lambda generation=2: 0)
"""stands in for the gc module in ManiSkill's `BaseEnv._clear` on the CPU (see `ActiveVisionFindEnv._clear`)"""


def _check_choice(name, value, valid):
    if value not in valid:
        raise ValueError(f"{name}={value!r} is not one of: {', '.join(map(str, valid))}")


@register_env("ActiveVisionFind-v0", max_episode_steps=100)
class ActiveVisionFindEnv(BaseEnv):
    SUPPORTED_ROBOTS = ["iiwa_wristcam"]
    SUPPORTED_OBS_MODES = OBS_MODES
    SUPPORTED_REWARD_MODES = REWARD_MODES
    agent: IiwaWristCam

    placement_radius = (0.70, 0.90)
    placement_azimuth = math.radians(155)
    min_object_distance = 0.15
    fixed_layout = (
        (0.80, 30.0),
        (0.75, -40.0),
        (0.85, 90.0),
        (0.80, -110.0),
        (0.75, 150.0),
        (0.85, -150.0),
        (0.72, -5.0),
        (0.88, 60.0),
    )
    """(radius m, azimuth deg) of each object slot for placement="fixed"; slot 0 is the target."""
    fixed_scene_seed = 0
    same_color_prob = 0.5
    same_shape_prob = 0.25
    studio_pos = (0.0, 0.0, -5.0)
    """Where the target's copy is photographed: below the floor, out of the wrist camera's sight."""
    max_objects = len(fixed_layout)
    cull = True
    """skip, in each capture, the bodies out of the camera's view (the same images; False draws them all, as
    ManiSkill does: `baselines/profile_step.py` compares both)"""
    collect_every = 10
    """a full garbage collection at every this many new scenes on the CPU (ManiSkill: every one; see `_clear`)"""
    min_visible_fraction = MIN_VISIBLE_FRACTION
    """success needs at least this share of the target's pixels in view not hidden by a panel"""

    def __init__(
        self,
        *args,
        robot_uids="iiwa_wristcam",
        num_objects: int = 5,
        object_set: str = "train",
        placement: str = "random",
        start_pose: str = "sky",
        step_size: float = 0.05,
        success_fraction: float = 0.05,
        success_center_tol: float = 0.15,
        terminate_on_success: bool = False,
        target_image_size: int = 64,
        occluders: int = 0,
        render_free: bool = False,
        num_envs: int = 1,
        reconfiguration_freq: int | None = None,
        obs_mode: str | None = None,
        reward_mode: str | None = None,
        control_mode: str | None = None,
        **kwargs,
    ):
        _check_choice("object_set", object_set, OBJECT_SETS)
        _check_choice("placement", placement, PLACEMENTS)
        _check_choice("start_pose", start_pose, START_POSES)
        for name, value in (("obs_mode", obs_mode), ("reward_mode", reward_mode), ("control_mode", control_mode)):
            if value is not None:
                _check_choice(
                    name, value, dict(obs_mode=OBS_MODES, reward_mode=REWARD_MODES, control_mode=CONTROL_MODES)[name]
                )
        if not (isinstance(num_objects, (int, np.integer)) and 1 <= num_objects <= self.max_objects):
            raise ValueError(f"num_objects={num_objects!r} must be an integer from 1 to {self.max_objects}")
        if not (isinstance(occluders, (int, np.integer)) and 0 <= occluders <= num_objects):
            raise ValueError(
                f"occluders={occluders!r} must be an integer from 0 to num_objects={num_objects} (one panel in "
                "front of each of the first `occluders` objects)"
            )
        if render_free and (obs_mode is None or "rgb" in obs_mode or "segmentation" in obs_mode):
            raise ValueError(
                f"render_free=True renders nothing, so obs_mode={obs_mode!r} has no images to give: use one of "
                "state, state_dict, none"
            )
        if render_free and occluders:
            raise ValueError(
                f"render_free=True projects the target alone: nothing hides it, so occluders={occluders!r} must be 0"
            )
        if not 0 < step_size <= 0.1:
            raise ValueError(f"step_size={step_size!r} must be in (0, 0.1] m")
        if not 0 < success_fraction <= 1:
            raise ValueError(f"success_fraction={success_fraction!r} must be in (0, 1]")
        if not 0 < success_center_tol <= 0.5:
            raise ValueError(f"success_center_tol={success_center_tol!r} must be in (0, 0.5]")
        if not (isinstance(target_image_size, (int, np.integer)) and 16 <= target_image_size <= 512):
            raise ValueError(f"target_image_size={target_image_size!r} must be an integer from 16 to 512")
        self.num_objects = int(num_objects)
        self.occluders = int(occluders)
        self.render_free = bool(render_free)
        self.object_set = object_set
        self.placement = placement
        self.start_pose = start_pose
        self.step_size = float(step_size)
        self.success_fraction = float(success_fraction)
        self.success_center_tol = float(success_center_tol)
        self.terminate_on_success = terminate_on_success
        self.target_image_size = int(target_image_size)
        self.forget_view()
        self._clears = 0
        self._camera_model = None
        if reconfiguration_freq is None:
            reconfiguration_freq = 1 if num_envs == 1 else 0
        super().__init__(
            *args,
            robot_uids=robot_uids,
            num_envs=num_envs,
            reconfiguration_freq=reconfiguration_freq,
            obs_mode=obs_mode,
            reward_mode=reward_mode,
            control_mode=control_mode,
            **kwargs,
        )

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self):
        # The studio camera photographs the target's copy; it is captured once per episode, not every step.
        size = self.target_image_size
        # From the wrist camera's elevation, looking along +x; the copy is turned so that this is the side
        # the robot sees (`_initialize_episode`).
        look_at = np.array(self.studio_pos) + [0, 0, 0.04]
        eye = look_at + 0.22 * np.array([-math.cos(CAMERA_PITCH), 0, math.sin(CAMERA_PITCH)])
        return [
            CameraConfig("target_camera", sapien_utils.look_at(eye, look_at), size, size, math.radians(40), 0.01, 2.0)
        ]

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at([1.6, -1.4, 1.6], [0.3, 0.0, 0.4])
        return CameraConfig("render_camera", pose, 512, 512, 1.0, 0.01, 100)

    def _setup_sensors(self, options: dict):
        super()._setup_sensors(options)
        # Saves the renderer ~14 s of CPU per process on software Vulkan (mani_active_vision.brdf_lut).
        supply_brdf_lut([*self._sensors.values(), *self._human_render_cameras.values()])

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose())

    def _load_scene(self, options: dict):
        self._culler = ViewCuller()
        self.ground = build_floor(self.scene)
        models = object_set(self.object_set)
        slots = [[] for _ in range(self.num_objects)]
        copies, bottoms, self.object_names, self.object_colors = [], [], [], []
        self._target_models, self._target_hulls = [], None  # hulls made on the first projection
        for env in range(self.num_envs):
            rng = (
                np.random.RandomState(self.fixed_scene_seed)
                if self.placement == "fixed"
                else self._batched_episode_rng[env]
            )
            picks = rng.choice(len(models), self.num_objects, replace=False)
            chosen = [models[i] for i in picks]
            colors = [m.color for m in chosen]
            for k in range(1, self.num_objects):  # distractors that look like the target
                if rng.rand() < self.same_shape_prob:  # ... in another colour: never an identical twin
                    chosen[k] = chosen[0]
                    others = [c for c in PALETTE if not np.allclose(c, colors[0])]
                    colors[k] = others[rng.randint(len(others))]
                elif rng.rand() < self.same_color_prob:
                    colors[k] = colors[0]
            sizes = rng.uniform(*OBJECT_SIZE, size=self.num_objects)
            env_bottoms = []
            for k, (model, color, size) in enumerate(zip(chosen, colors, sizes)):
                actor, bottom = build_object(self.scene, model, size, color, f"env{env}_object{k}_{model.name}", [env])
                self.remove_from_state_dict_registry(actor)
                slots[k].append(actor)
                env_bottoms.append(bottom)
            copy, _ = build_object(self.scene, chosen[0], sizes[0], colors[0], f"env{env}_target_copy", [env])
            self.remove_from_state_dict_registry(copy)
            copies.append(copy)
            bottoms.append(env_bottoms)
            self._target_models.append((chosen[0], float(sizes[0])))
            self.object_names.append([m.name for m in chosen])
            self.object_colors.append([tuple(float(c) for c in color) for color in colors])
        self.objects = [Actor.merge(actors, name=f"object_{k}") for k, actors in enumerate(slots)]
        for obj in self.objects:
            self.add_to_state_dict_registry(obj)
        self.target = self.objects[0]
        self.panels = [
            Actor.merge(
                [build_panel(self.scene, f"env{env}_panel{k}", [env]) for env in range(self.num_envs)], f"panel_{k}"
            )
            for k in range(self.occluders)
        ]
        for panel in self.panels:
            self.add_to_state_dict_registry(panel)
        self.target_copy = Actor.merge(copies, name="target_copy")
        self.add_to_state_dict_registry(self.target_copy)
        self._object_bottoms = torch.tensor(bottoms, dtype=torch.float32, device=self.device)
        self._target_image = torch.zeros(
            (self.num_envs, self.target_image_size, self.target_image_size, 3), dtype=torch.uint8, device=self.device
        )
        self._target_image_stale = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)

    @property
    def target_seg_id(self) -> torch.Tensor:
        """Segmentation id (N,) of the target in the wrist camera's `segmentation` image."""
        return self.target.per_scene_id

    # ------------------------------------------------------------------ episodes
    def _sample_layout(self, env_idx) -> tuple[np.ndarray, np.ndarray]:
        """(b, K, 3) = x, y, yaw of every object slot, and (b, occluders, 3) of every panel."""
        layouts, panels = [], []
        for env in np.asarray(env_idx.cpu()):
            rng = self._batched_episode_rng[env]
            if self.placement == "fixed":
                r, az = np.array(self.fixed_layout[: self.num_objects]).T
                xy = np.stack([r * np.cos(np.radians(az)), r * np.sin(np.radians(az))], -1)
                fixed_rng = np.random.RandomState(self.fixed_scene_seed)
                yaw = fixed_rng.uniform(0, 2 * np.pi, self.num_objects)
                layouts.append(np.concatenate([xy, yaw[:, None]], -1))
                fixed_panels = place_panels(fixed_rng, xy, self.occluders, self._search_camera_rz())
                if fixed_panels is None:  # the fixed scene has one layout: there is no other to draw
                    raise ValueError(f"occluders={self.occluders} find no free spot in the fixed scene")
                panels.append(fixed_panels)
                continue
            while True:  # a new layout when the panels find no room (rare; never with occluders=0)
                placed = self._place_objects(rng)
                env_panels = place_panels(rng, placed[:, :2], self.occluders, self._search_camera_rz())
                if env_panels is not None:
                    break
            layouts.append(placed)
            panels.append(env_panels)
        return np.stack(layouts), np.stack(panels)

    def _place_objects(self, rng: np.random.RandomState) -> np.ndarray:
        placed = []
        while len(placed) < self.num_objects:
            for _ in range(1000):
                r = rng.uniform(*self.placement_radius)
                az = rng.uniform(-self.placement_azimuth, self.placement_azimuth)
                xy = np.array([r * np.cos(az), r * np.sin(az)])
                if all(np.linalg.norm(xy - p[:2]) >= self.min_object_distance for p in placed):
                    break
            placed.append(np.array([*xy, rng.uniform(0, 2 * np.pi)]))
        return np.stack(placed)

    @staticmethod
    def _search_camera_rz() -> tuple[float, float]:
        """The camera's (radius, height) at the search pose: the panels hide objects from there."""
        camera = camera_end(torch.tensor([SEARCH_POS], dtype=torch.float64), CAMERA_PITCH)[0, 2]
        return float(torch.linalg.norm(camera[:2])), float(camera[2])

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            layout, panels = (torch.as_tensor(a, dtype=torch.float32) for a in self._sample_layout(env_idx))
            yaw_q = lambda yaw: torch.stack([torch.cos(yaw / 2), 0 * yaw, 0 * yaw, torch.sin(yaw / 2)], -1)
            for k, obj in enumerate(self.objects):
                p = torch.cat([layout[:, k, :2], self._object_bottoms[env_idx, k, None]], -1)
                obj.set_pose(Pose.create_from_pq(p, yaw_q(layout[:, k, 2])))
            for k, panel in enumerate(self.panels):
                p = torch.cat([panels[:, k, :2], torch.zeros(b, 1)], -1)
                panel.set_pose(Pose.create_from_pq(p, yaw_q(panels[:, k, 2])))
            studio = torch.tensor(self.studio_pos).expand(b, 3).clone()
            studio[:, 2] += self._object_bottoms[env_idx, 0]
            # The copy's yaw relative to the studio camera's view (+x) is the target's relative to the robot's
            # line of sight to it (outward, along its azimuth): the picture shows the side the robot sees.
            azimuth = torch.atan2(layout[:, 0, 1], layout[:, 0, 0])
            self.target_copy.set_pose(Pose.create_from_pq(studio, yaw_q(layout[:, 0, 2] - azimuth)))
            qpos = torch.as_tensor(self.agent.keyframes[self.start_pose].qpos, dtype=torch.float32).expand(b, -1)
            self.agent.reset(qpos)
            self.agent.controller.start_episode(env_idx, qpos)
            self._target_image_stale[env_idx] = True

    def _clear(self):
        # ManiSkill ends this with a full gc.collect(), to free GPU memory at once. On the CPU that walks every
        # object of the process (~300 ms, most of a reset with new objects); skipping it leaves the old scenes,
        # held in reference cycles, to Python's own rare full collections (RSS grew 190 MB over 1,000 resets).
        # Collecting at every `collect_every`-th new scene keeps memory flat at a tenth of the cost (docs/speed.md).
        self._clears += 1
        if self._sim_device.is_cuda() or self._clears % self.collect_every == 0:
            return super()._clear()
        sapien_env.gc = _NO_FORCED_COLLECTION
        try:
            super()._clear()
        finally:
            sapien_env.gc = gc

    def reset(self, seed=None, options=None):
        self.forget_view()
        if isinstance(seed, (int, np.integer)):
            gym.Env.reset(self, seed=int(seed))  # gymnasium's own seeding (env.np_random), which BaseEnv skips
        return super().reset(seed=seed, options=options)

    def forget_view(self):
        """Drop what was seen from the current view (the render, the panel-free count, the projected mask),
        which the task keeps for one step: call it after moving the arm or the scene by hand."""
        self._hand_images = self._unoccluded_pixels = self._projected_mask = None

    def panel_layout(self) -> torch.Tensor:
        """(N, occluders, 3) = x, y, yaw of every panel, from the actors' poses (so a restored state agrees)."""
        if not self.panels:
            return torch.zeros(self.num_envs, 0, 3, device=self.device)
        poses = [panel.pose for panel in self.panels]
        yaw = [2 * torch.atan2(pose.q[:, 3], pose.q[:, 0]) for pose in poses]
        return torch.stack([torch.cat([pose.p[:, :2], y[:, None]], -1) for pose, y in zip(poses, yaw)], 1)

    def step(self, action):
        self._check_action(action)
        self.forget_view()
        if self.panels:  # the controller keeps the camera end of the arm out of the panels
            self.agent.controller.panels = self.panel_layout()
        obs, reward, terminated, truncated, info = super().step(action)
        if not self.terminate_on_success:
            terminated = torch.zeros_like(terminated)
        return obs, reward, terminated, truncated, info

    def _check_action(self, action):
        """ManiSkill fails on a wrong action with a bare assertion or TypeError: say what is expected."""
        if action is None or isinstance(action, dict):
            return
        shape = tuple(action.shape) if hasattr(action, "shape") else np.shape(action)  # no copy off the GPU
        single = tuple(self.single_action_space.shape)
        if shape not in (single, (self.num_envs, *single)):
            expected = f"{single} or {(1, *single)}" if self.num_envs == 1 else f"{(self.num_envs, *single)}"
            raise ValueError(
                f"action of shape {shape} ({action!r:.40}) does not fit control_mode={self.control_mode!r}: expected a "
                f"Cartesian step of shape {expected} (metres). For the six discrete directions (an index), wrap the "
                "env in mani_active_vision.DiscreteDirections, or build it with mani_active_vision.make_env"
            )

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        self.forget_view()
        super().set_state_dict(state, env_idx)

    # ------------------------------------------------------------------ sensing
    def _capture(self, name: str, rgb: bool) -> dict:
        """Render sensor `name`, skipping the bodies out of its view (`mani_active_vision.culling`: the same
        images), and read back its segmentation and, with `rgb`, its colour."""
        camera = self._sensors[name]
        if self.cull and not self.gpu_sim_enabled:
            self._culler.cull(camera.camera._render_cameras[0], self.scene.sub_scenes[0].render_system.render_bodies)
        else:
            self._culler.show_all()
        self.scene.update_render(update_sensors=True, update_human_render_cameras=False)
        camera.capture()
        return camera.get_obs(rgb=rgb, depth=False, position=False, segmentation=True)

    def render(self):
        self._culler.show_all()  # the human render cameras see everything
        return super().render()

    def _hand_camera_images(self) -> dict:
        """The wrist camera's rgb and segmentation, rendered once per step (reward and obs share it)."""
        if self._hand_images is None:
            self._hand_images = self._capture("hand_camera", rgb=self.obs_mode_struct.visual.rgb)
        return self._hand_images

    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        visual = self.obs_mode_struct.visual
        images = self._hand_camera_images()
        return dict(hand_camera={k: v for k, v in images.items() if getattr(visual, k, False)})

    def get_sensor_params(self):
        # ManiSkill returns its cached intrinsics; copy so that observations never share memory.
        return dict(hand_camera={k: v.clone() for k, v in self._sensors["hand_camera"].get_params().items()})

    def _render_target_image(self) -> torch.Tensor:
        """Photograph the target's copy in the studio once per episode; non-target pixels grey."""
        if self._target_image_stale.any():
            images = self._capture("target_camera", rgb=True)
            alone = images["segmentation"][..., 0] == self.target_copy.per_scene_id[:, None, None]
            image = torch.where(alone[..., None], images["rgb"], torch.full_like(images["rgb"], 128))
            stale = self._target_image_stale
            self._target_image[stale] = image[stale]
            self._target_image_stale[:] = False
        return self._target_image

    def _target_pixels_without_panels(self) -> torch.Tensor:
        """Target pixels (N,) in the wrist view with the panels hidden: one more render, made only on steps
        where the target borders a panel (docs/task.md#occluders measures the cost)."""
        if self._unoccluded_pixels is None:
            bodies = [
                component
                for panel in self.panels
                for entity in panel._objs
                for component in entity.components
                if isinstance(component, sapien.render.RenderBodyComponent) and component.visibility > 0
            ]
            for body in bodies:
                body.visibility = 0
            try:
                segmentation = self._capture("hand_camera", rgb=False)["segmentation"][..., 0]
            finally:
                for body in bodies:
                    body.visibility = 1
            self._unoccluded_pixels = (segmentation == self.target_seg_id.to(segmentation.device)[:, None, None]).sum(
                (1, 2)
            )
        return self._unoccluded_pixels

    def _visible_fraction(self, segmentation: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The share (N,) of the target's pixels in this view that no panel hides (0 when none is seen). A
        panel hides part of the target only where its pixels border the target's, so only then is the view
        rendered again without the panels to count what they hide."""
        pixels = target.sum((1, 2))
        fraction = (pixels > 0).float()
        if not self.panels:
            return fraction
        panel_ids = torch.stack([panel.per_scene_id for panel in self.panels], -1).to(segmentation.device)
        panel = (segmentation[..., None] == panel_ids[:, None, None, :]).any(-1)
        near_panel = torch.nn.functional.max_pool2d(panel[:, None].float(), 3, 1, 1)[:, 0] > 0
        borders = (near_panel & target).any(2).any(1)
        if borders.any():
            unoccluded = self._target_pixels_without_panels()
            fraction = torch.where(borders, pixels / unoccluded.clamp(min=1), fraction)
        return fraction

    def projected_target_mask(self) -> torch.Tensor:
        """(N, H, W) bool: the target's convex hull projected into the wrist camera, nothing rendered
        (`mani_active_vision.projection`)."""
        if self._projected_mask is None:  # once per step: the reward, the info and the box state share it
            camera = self._sensors["hand_camera"]
            if self._camera_model is None:  # (intrinsic, local pose): fixed for the env's life
                local = camera.config.pose
                self._camera_model = (
                    camera.camera.get_intrinsic_matrix().cpu().numpy(),
                    Pose.create(local).raw_pose[0].cpu().numpy(),
                )
            intrinsic, local_pose = self._camera_model
            target = self.target.pose.raw_pose.cpu().numpy()  # (N, 7)
            if self._target_hulls is None:  # envs' hulls padded to one length by repeating a point
                hulls = [hull_points(model, size) for model, size in self._target_models]
                most = max(len(h) for h in hulls)
                self._target_hulls = np.stack([np.concatenate([h, np.repeat(h[-1:], most - len(h), 0)]) for h in hulls])
            points = self._target_hulls @ rotation_matrix(target[:, 3:]).transpose(0, 2, 1) + target[:, None, :3]
            extrinsic = extrinsic_cv(camera.config.mount.pose.raw_pose.cpu().numpy(), local_pose)
            self._projected_mask = hull_mask(points, extrinsic, intrinsic, camera.config.width).to(self.device)
        return self._projected_mask

    def evaluate(self) -> dict:
        if self.render_free:
            target = self.projected_target_mask()
            stats = target_stats(target)
            visible_fraction = stats["target_visible"].float()
        else:
            segmentation = self._hand_camera_images()["segmentation"][..., 0]
            target = segmentation == self.target_seg_id.to(segmentation.device)[:, None, None]
            stats = target_stats(target)
            visible_fraction = self._visible_fraction(segmentation, target)
        success = (
            stats["target_visible"]
            & ~stats["touches_border"]
            & (visible_fraction >= self.min_visible_fraction)
            & (stats["center_offset"] <= self.success_center_tol)
            & (stats["target_fraction"] >= self.success_fraction)
        )
        controller = self.agent.controller
        return dict(
            success=success,
            target_fraction=stats["target_fraction"],
            target_visible=stats["target_visible"],
            target_visible_fraction=visible_fraction,
            target_bbox=stats["target_bbox"],
            target_center_offset=stats["center_offset"],
            refused=controller.refused.clone(),
            refused_count=controller.refused_count.clone(),
        )

    def _get_obs_extra(self, info: dict):
        if self.obs_mode_struct.visual.rgb:
            return dict(target_image=self._render_target_image().clone())
        return dict(
            ee_pos=self.agent.ee_pose.p,
            target_pos=self.target.pose.p,
            target_bbox=info["target_bbox"],
            target_fraction=info["target_fraction"][:, None],
        )

    # ------------------------------------------------------------------ reward
    def compute_dense_reward(self, obs, action, info):
        return info["target_fraction"]

    def compute_normalized_dense_reward(self, obs, action, info):
        return (info["target_fraction"] / self.success_fraction).clamp(max=1.0)
