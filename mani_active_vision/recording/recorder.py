"""The recording wrappers: everything that passes through `reset` and `step` is logged, whatever the policy.

`RerunRecorder` wraps the outermost env (usually `make_env(config)`: task -> DiscreteDirections ->
BoxState), so it sees direction indices, and reads the wrist observation and the box state's mask from
the `BoxState` inside it in the same call (docs/design.md §13). Observations and `info` are batch-first
(N, ...): each env of a batched ManiSkill env is logged under its own `env{i}`. `RerunVectorRecorder` does
the same for a gymnasium vector env whose sub-envs return ManiSkill's observation dict.

Per step: the wrist RGB (JPEG by default), its ground-truth segmentation with the objects named, the
ground-truth box, the box state's mask and box, the action's name, reward, target fraction, success, the
camera's pose and pinhole (a frustum in the 3D view) and the end-effector path (traced by the wrist
camera's optical centre, which rides on link 7). Per episode: the target image, the objects and the outcome.
Timelines: `step` (global: one tick per observation, resets included) and `episode`.
"""

from __future__ import annotations

import os
import time
import uuid

import gymnasium as gym
import numpy as np
import rerun as rr
import torch

from mani_active_vision.box_state import BoxState
from mani_active_vision.boxes import mask_to_box
from mani_active_vision.directions import action_count, action_names_for
from mani_active_vision.occluders import PANEL_SIZE
from mani_active_vision.recording import log
from mani_active_vision.recording.blueprint import blueprint

IMAGE_FORMATS = ("jpeg", "raw")


def _action_names(space: gym.Space | None) -> tuple[str, ...]:
    """The names of a discrete action space's actions (`action_names_for`), else the default set."""
    if isinstance(space, (gym.spaces.Discrete, gym.spaces.MultiDiscrete)):
        return action_names_for(action_count(space))
    return log.DEFAULT_NAMES


def check_writable(path: str) -> None:
    """Fail before any rollout if the recording cannot be written (creates the parent folder)."""
    if not str(path).endswith(".rrd"):
        raise ValueError(f"recording path {path!r} must end in .rrd")
    try:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, "wb"):
            pass
    except OSError as e:
        raise OSError(f"cannot write the recording to {path!r}: {e.strerror or e}") from e


class Recording:
    """One `.rrd` file and what is logged to it, episode by episode, for `num_envs` envs; the wrappers
    below call it. `close()` writes the file's footer (safe to call twice)."""

    def __init__(
        self,
        path: str,
        num_envs: int,
        image_format: str = "jpeg",
        jpeg_quality: int = 90,
        application_id: str = "mani_active_vision",
        action_space: gym.Space | None = None,
    ):
        if image_format not in IMAGE_FORMATS:
            raise ValueError(f"image_format={image_format!r} is not one of: {', '.join(IMAGE_FORMATS)}")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r} must be from 1 to 100")
        check_writable(path)
        self.path, self.num_envs = str(path), num_envs
        self.jpeg_quality = int(jpeg_quality) if image_format == "jpeg" else None
        self.stream = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self.stream.save(self.path, default_blueprint=blueprint(num_envs))
        self.step = -1  # the global `step` timeline: one tick per observation
        self.episode = np.full(num_envs, -1)  # the `episode` timeline, per env
        self.episodes = [None] * num_envs  # per env: return, steps, first success, path, done
        self.mask_context_logged = False
        self.action_names = _action_names(action_space)
        self.seconds = 0.0  # time spent logging
        self.closed = False

    def at(self, i: int):
        self.stream.set_time("step", sequence=self.step)
        self.stream.set_time("episode", sequence=int(self.episode[i]))

    def start_episodes(self, obs: dict, env_ids, scene):
        """Env ids starting an episode; `scene(i)` gives (classes, object positions, labels, colours)."""
        intrinsics = _numpy(obs["sensor_param"]["hand_camera"]["intrinsic_cv"])
        height, width = obs["sensor_data"]["hand_camera"]["rgb"].shape[-3:-1]
        target_images = _numpy(obs["extra"]["target_image"]) if "target_image" in obs.get("extra", {}) else None
        for i in env_ids:
            self.episode[i] += 1
            self.episodes[i] = dict(ret=0.0, steps=0, first_success=None, path=[], done=False)
            self.at(i)
            classes, positions, labels, colors = scene(i)
            log.log_episode_start(
                self.stream,
                i,
                int(self.episode[i]),
                classes,
                intrinsics[i],
                width,
                height,
                None if target_images is None else target_images[i],
                positions,
                labels,
                colors,
            )

    def frame(self, obs: dict, info: dict, mask=None, mask_source: str = ""):
        """The observation of every env (and the box state's mask (N, H, W), when there is one)."""
        camera = obs["sensor_data"]["hand_camera"]
        rgb = _numpy(camera["rgb"])
        if rgb.ndim != 4 or len(rgb) != self.num_envs:
            raise ValueError(
                f"the recorder needs batch-first observations (N={self.num_envs}, H, W, 3), got rgb of "
                f"shape {rgb.shape}: put RerunRecorder inside CPUGymWrapper, or use RerunVectorRecorder"
            )
        segmentation = _numpy(camera["segmentation"])[..., 0] if "segmentation" in camera else None
        extrinsics = _numpy(obs["sensor_param"]["hand_camera"]["extrinsic_cv"])
        boxes = _numpy(info["target_bbox"]) if "target_bbox" in info else None
        if mask is not None:
            mask = torch.as_tensor(mask).reshape(self.num_envs, *rgb.shape[1:3]).cpu()
            mask_boxes, mask = mask_to_box(mask).numpy(), mask.numpy()
        for i in range(self.num_envs):
            self.at(i)
            centre = log.log_camera_frame(
                self.stream,
                i,
                rgb[i],
                extrinsics[i],
                None if segmentation is None else segmentation[i],
                None if boxes is None else boxes[i],
                self.jpeg_quality,
            )
            if mask is not None:
                log.log_mask(
                    self.stream, i, mask_source, mask[i], mask_boxes[i], with_context=not self.mask_context_logged
                )
            episode = self.episodes[i]
            if not episode["done"]:
                episode["path"].append(centre)
            log.log_ee_path(self.stream, i, episode["path"])
        self.mask_context_logged |= mask is not None

    def transition(self, action, reward, terminated, truncated, info, env_ids) -> np.ndarray:
        """The step of each env in env_ids; returns which envs' episodes ended (all envs)."""
        n = self.num_envs
        actions = _numpy(action).reshape(n, -1)
        reward = _numpy(reward).reshape(n)
        success = _numpy(info["success"]).reshape(n)
        fraction = _numpy(info["target_fraction"]).reshape(n) if "target_fraction" in info else None
        refused = _numpy(info["refused"]).reshape(n) if "refused" in info else np.zeros(n, bool)
        done = _numpy(terminated).reshape(n) | _numpy(truncated).reshape(n)
        for i in env_ids:
            episode = self.episodes[i]
            if episode["done"]:  # ManiSkill keeps stepping finished envs of a batch until the next reset
                continue
            self.at(i)
            episode["steps"] += 1
            episode["ret"] += float(reward[i])
            if success[i] and episode["first_success"] is None:
                episode["first_success"] = episode["steps"]
            log.log_transition(
                self.stream,
                i,
                actions[i],
                bool(refused[i]),
                reward[i],
                bool(success[i]),
                None if fraction is None else fraction[i],
                self.action_names,
            )
            if done[i]:
                self.end_episode(i, bool(success[i]), None if fraction is None else fraction[i], "ended")
        return done

    def end_episode(self, i: int, success_now: bool, fraction, how: str):
        episode = self.episodes[i]
        episode["done"] = True
        first = episode["first_success"]
        text = (
            f"episode {self.episode[i]} {how} after {episode['steps']} steps: "
            f"{'success' if success_now else 'no success'} at the end, "
            f"{'first success at step ' + str(first) if first else 'never successful'}, return {episode['ret']:.3f}"
            + (f", final target fraction {float(fraction):.3f}" if fraction is not None else "")
        )
        log.log_outcome(self.stream, i, text, success_now)

    def end_unfinished(self, how: str):
        for i, episode in enumerate(self.episodes):
            if episode is not None and not episode["done"]:
                self.at(i)
                self.end_episode(i, False, None, how)

    def close(self):
        """Close the episodes in progress ("interrupted") and write the file's footer. Safe to call twice."""
        if self.closed:
            return
        self.closed = True
        try:
            self.end_unfinished("interrupted")
        finally:
            self.stream.flush()
            self.stream.disconnect()  # drops the file sink: writes the footer


class _Timed:
    """Times the wrapped env's steps apart from logging, for `overhead()`."""

    def _start_timing(self):
        self.env_seconds, self.env_steps, self.reset_log_seconds = 0.0, 0, 0.0

    def overhead(self) -> dict:
        """Logging time per step (ms) and as a share of the wrapped env's step time; resets apart."""
        steps = max(self.env_steps, 1)
        step_log_seconds = self.recording.seconds
        return dict(
            steps=self.env_steps,
            log_ms_per_step=1e3 * step_log_seconds / steps,
            reset_log_seconds=self.reset_log_seconds,
            env_ms_per_step=1e3 * self.env_seconds / steps,
            log_share_of_env_step=step_log_seconds / max(self.env_seconds, 1e-9),
        )

    def _timed(self, call, *args, **kwargs):
        start = time.perf_counter()
        result = call(*args, **kwargs)
        self.env_seconds += time.perf_counter() - start
        self.env_steps += 1
        return result

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()  # also on an exception or Ctrl-C: the file gets its footer
        return False


class RerunRecorder(_Timed, gym.Wrapper):
    """Log every `reset` and `step` of a ManiSkill env (batched or not, possibly wrapped, e.g. by
    `make_env`) to a Rerun file; see the module docstring.

    path: the `.rrd` file (its folder is created; an unwritable path fails here, before any rollout).
    image_format: "jpeg" (default, ~10x smaller) or "raw" for the wrist RGB. jpeg_quality: 1-100.
    """

    def __init__(
        self,
        env: gym.Env,
        path: str,
        image_format: str = "jpeg",
        jpeg_quality: int = 90,
        application_id: str = "mani_active_vision",
    ):
        gym.Wrapper.__init__(self, env)
        self.box_state = _find_box_state(env)
        self.recording = Recording(
            path, env.unwrapped.num_envs, image_format, jpeg_quality, application_id, env.action_space
        )
        self.path = self.recording.path
        self._start_timing()

    def reset(self, **kwargs):
        self.recording.end_unfinished("reset")
        obs, info = self.env.reset(**kwargs)
        start = time.perf_counter()
        self.recording.step += 1
        raw = self._observation(obs)
        self.recording.start_episodes(raw, range(self.recording.num_envs), self._scene)
        base = self.env.unwrapped
        if getattr(base, "panels", None):
            for i in range(self.recording.num_envs):
                log.log_occluders(self.recording.stream, i, _numpy(base.panel_layout()[i]), PANEL_SIZE)
        self._frame(raw, info)
        self.reset_log_seconds += time.perf_counter() - start
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self._timed(self.env.step, action)
        start = time.perf_counter()
        self.recording.step += 1
        self.recording.transition(action, reward, terminated, truncated, info, range(self.recording.num_envs))
        self._frame(self._observation(obs), info)
        self.recording.seconds += time.perf_counter() - start
        return obs, reward, terminated, truncated, info

    def close(self):
        """Write what is pending and the file's footer, then close the env. Safe to call twice."""
        try:
            self.recording.close()
        finally:
            gym.Wrapper.close(self)

    def _observation(self, obs) -> dict:
        """ManiSkill's observation dict: the env's own, or the one the BoxState inside made its box from."""
        if isinstance(obs, dict):
            return obs
        if self.box_state is None:
            raise ValueError("RerunRecorder needs ManiSkill's observation dict or a BoxState inside it")
        return self.box_state.last_observation

    def _frame(self, raw: dict, info: dict):
        if self.box_state is None:
            self.recording.frame(raw, info)
        else:
            self.recording.frame(raw, info, self.box_state.last_mask, self.box_state.source)

    def _scene(self, i):
        return scene_classes(self.env.unwrapped, i)


class RerunVectorRecorder(_Timed, gym.vector.VectorWrapper):
    """The same recording for a gymnasium vector env whose sub-envs return ManiSkill's observation dict
    (e.g. `AsyncVectorEnv` of `CPUGymWrapper` envs): obs and info come stacked (N, ...) as numpy. Sub-envs
    reset automatically in gymnasium's default NEXT_STEP mode: the step after an episode's end brings the
    next episode's first observation, which starts that env's next `episode` here. Segmentation classes
    name only the target (the other objects' ids stay in the sub-env processes); no object positions."""

    def __init__(
        self,
        env: gym.vector.VectorEnv,
        path: str,
        image_format: str = "jpeg",
        jpeg_quality: int = 90,
        application_id: str = "mani_active_vision",
    ):
        gym.vector.VectorWrapper.__init__(self, env)
        mode = env.metadata.get("autoreset_mode", gym.vector.AutoresetMode.NEXT_STEP)
        if mode != gym.vector.AutoresetMode.NEXT_STEP:
            raise ValueError(f"autoreset_mode={mode!r} is not supported; use {gym.vector.AutoresetMode.NEXT_STEP!r}")
        self.recording = Recording(path, env.num_envs, image_format, jpeg_quality, application_id, env.action_space)
        self.path = self.recording.path
        self._restarting = np.zeros(env.num_envs, bool)
        self._names = self._target_ids = None
        self._start_timing()

    def reset(self, **kwargs):
        self.recording.end_unfinished("reset")
        self._names = self._target_ids = None  # new scenes in every sub-env
        self._restarting[:] = False
        obs, info = self.env.reset(**kwargs)
        start = time.perf_counter()
        self.recording.step += 1
        self.recording.start_episodes(obs, range(self.num_envs), self._scene)
        self.recording.frame(obs, info)
        self.reset_log_seconds += time.perf_counter() - start
        return obs, info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self._timed(self.env.step, actions)
        start = time.perf_counter()
        self.recording.step += 1
        restarted = np.flatnonzero(self._restarting)
        self._names = self._target_ids = None
        if len(restarted):
            self.recording.start_episodes(obs, restarted, self._scene)
        done = self.recording.transition(
            actions, reward, terminated, truncated, info, np.flatnonzero(~self._restarting)
        )
        self._restarting = done & ~self._restarting
        self.recording.frame(obs, info)
        self.recording.seconds += time.perf_counter() - start
        return obs, reward, terminated, truncated, info

    def close(self, **kwargs):
        try:
            self.recording.close()
        finally:
            gym.vector.VectorWrapper.close(self, **kwargs)

    def _scene(self, i):
        if self._names is None:  # one round trip to the sub-envs per batch of episode starts
            self._names = self.env.get_attr("object_names")
            self._target_ids = self.env.get_attr("target_seg_id")
        target_id = int(_numpy(self._target_ids[i]).reshape(-1)[0])
        classes = [(0, "background", (0, 0, 0, 0)), (target_id, f"target: {self._names[i][0][0]}", log.TARGET_COLOR)]
        return classes, None, None, None


def scene_classes(base, i: int):
    """Segmentation classes of env i (id, label, colour) from the task's objects and ManiSkill's
    `segmentation_id_map`, and the objects' positions, labels and colours for the 3D view."""
    classes = [(0, "background", (0, 0, 0, 0))]
    for seg_id, thing in getattr(base, "segmentation_id_map", {}).items():
        name = getattr(thing, "name", "")
        if type(thing).__name__ == "Link":
            classes.append((int(seg_id), f"robot {name}", log.ROBOT_COLOR))
        elif name == "ground":
            classes.append((int(seg_id), "ground", log.GROUND_COLOR))
    objects = getattr(base, "objects", None)
    if objects is None:
        return classes, None, None, None
    names = base.object_names[i]
    labels = [f"target: {names[0]}"] + [f"distractor {k}: {names[k]}" for k in range(1, len(names))]
    colors = [log.TARGET_COLOR] + [
        log.DISTRACTOR_COLORS[(k - 1) % len(log.DISTRACTOR_COLORS)] for k in range(1, len(names))
    ]
    for obj, label, color in zip(objects, labels, colors):
        classes.append((int(obj.per_scene_id[i]), label, color))
    for k, panel in enumerate(getattr(base, "panels", [])):
        classes.append((int(panel.per_scene_id[i]), f"occluder {k}", log.OCCLUDER_COLOR))
    positions = np.stack([_numpy(obj.pose.p[i]) for obj in objects])
    return classes, positions, labels, colors


def _find_box_state(env: gym.Env) -> BoxState | None:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, BoxState):
            return env
        env = env.env
    return None


def _numpy(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return np.asarray(x)
