"""Record rollouts of ActiveVisionFind-v0 to a Rerun `.rrd` file that anyone can replay offline.

`RerunRecorder` is a gymnasium wrapper: put it around the env the policy's actions go into (usually
`DiscreteDirections(gym.make(...))`, so that it sees direction indices and ManiSkill's observation dict),
and everything that passes through `reset` and `step` is logged, whatever the policy. Observations and
`info` are batch-first (N, ...): every env of a batched ManiSkill env is logged under its own `env{i}`.
`RerunVectorRecorder` does the same for a gymnasium vector env (e.g. `AsyncVectorEnv` of `CPUGymWrapper`
envs, with their automatic resets). `screenshots()` renders a file to PNGs in a headless viewer.

Per step: the wrist camera's RGB (JPEG by default), its ground-truth segmentation with the objects named
(an `AnnotationContext`), the ground-truth box, the action's name, reward, target share, success, the
camera's pose (`Transform3D` + `Pinhole`: a frustum in the 3D view) and the end-effector path (traced by
the wrist camera's optical centre, which rides on link 7). With a `BoxState` outside the recorder
(`recorder.show_masks_of(box_state)`), the mask its box came from (`last_mask`; the FCN's prediction
when `source="fcn"`) and that box. Per episode: the target image, the objects and the outcome.

Timelines: `step` (global: one tick per observation, resets included) and `episode`. The blueprint
(the viewer's layout) is stored in the file. `close()` (also on exceptions and Ctrl-C, when used as a
context manager or with try/finally) writes the file's footer, so an interrupted run leaves a valid file.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading
import time
import uuid
import warnings

import gymnasium as gym
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import torch

from mani_active_vision.boxes import mask_to_box
from mani_active_vision.directions import DIRECTIONS

IMAGE_FORMATS = ("jpeg", "raw")
TARGET_COLOR = (230, 40, 40)
DISTRACTOR_COLORS = [(40, 120, 230), (40, 190, 90), (230, 170, 30), (170, 60, 210), (30, 200, 200), (240, 110, 180), (140, 140, 40)]
ROBOT_COLOR = (150, 150, 150)
GROUND_COLOR = (0, 0, 0, 0)  # transparent: the overlay highlights objects and the robot, not the floor
MASK_COLOR = (255, 220, 0)


def blueprint(num_envs: int = 1) -> rrb.Blueprint:
    """The viewer layout: per env, the wrist camera (rgb, segmentation, boxes, mask) and the target image,
    a 3D view (camera frustum, end-effector path, objects) and plots of reward, target share and success
    with the action log. One tab per env when there are several."""
    def env_layout(i: int):
        cam = f"world/env{i}/camera/image"
        return rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name=f"env{i} wrist camera", origin=cam),
                rrb.Spatial2DView(name=f"env{i} target image", origin=f"env{i}/target_image"),
                row_shares=[3, 2],
            ),
            rrb.Spatial3DView(name=f"env{i} 3D", origin=f"world/env{i}"),
            rrb.Vertical(
                rrb.TimeSeriesView(name="reward and target share", origin=f"env{i}",
                                   contents=[f"env{i}/reward", f"env{i}/target_fraction"]),
                rrb.TimeSeriesView(name="success", origin=f"env{i}", contents=[f"env{i}/success"]),
                rrb.TextLogView(name="actions and outcomes", origin=f"env{i}"),
            ),
            column_shares=[2, 3, 2],
            name=f"env{i}",
        )

    layout = env_layout(0) if num_envs == 1 else rrb.Tabs(*[env_layout(i) for i in range(num_envs)])
    return rrb.Blueprint(layout, rrb.TimePanel(timeline="step"), collapse_panels=True)


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


class _Recording:
    """The logging shared by `RerunRecorder` (one ManiSkill env, batched or not) and
    `RerunVectorRecorder` (a gymnasium vector env); they call `_setup`, then the `_log_*` methods."""

    def _setup(self, path, image_format, jpeg_quality, application_id):
        """Needs `self.num_envs`."""
        if image_format not in IMAGE_FORMATS:
            raise ValueError(f"image_format={image_format!r} is not one of: {', '.join(IMAGE_FORMATS)}")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r} must be from 1 to 100")
        check_writable(path)
        self.path = str(path)
        self.image_format = image_format
        self.jpeg_quality = int(jpeg_quality)
        self.stream = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self.stream.save(self.path, default_blueprint=blueprint(self.num_envs))
        self.mask_source = None
        self.step_count = -1  # the global `step` timeline: one tick per observation
        self.episode = np.full(self.num_envs, -1)  # the `episode` timeline, per env
        self.log_seconds = 0.0  # time spent logging steps, for the overhead figure
        self.reset_log_seconds = 0.0  # logging at resets (the first one pays rerun's one-off start-up)
        self.env_seconds = 0.0  # time spent in the wrapped env's step
        self.env_steps = 0
        self._episodes = [None] * self.num_envs  # per env: return, steps, first success, path, done
        self._pending_mask = None
        self._mask_context_logged = False
        self._closed = False

    def _logged_reset(self, **kwargs):
        """Close the episodes in progress, reset the wrapped env and log every env's new episode."""
        self._log_pending_mask()
        self._finish_episodes("reset")
        obs, info = self.env.reset(**kwargs)
        start = time.perf_counter()
        self.step_count += 1
        self._log_episode_start(obs, range(self.num_envs))
        self._log_observation(obs, info)
        self.reset_log_seconds += time.perf_counter() - start
        return obs, info

    def _timed_env_step(self, action):
        """Step the wrapped env, counting its time apart from logging; returns its results and the end time."""
        self._log_pending_mask()
        start = time.perf_counter()
        result = self.env.step(action)
        stepped = time.perf_counter()
        self.env_seconds += stepped - start
        self.env_steps += 1
        self.step_count += 1
        return result, stepped

    def show_masks_of(self, box_state) -> None:
        """Also log the mask a `BoxState` wrapped around this recorder computed its box from (`last_mask`)."""
        self.mask_source = box_state

    def overhead(self) -> dict:
        """Logging time per step (ms) and as a share of the wrapped env's step time; resets apart."""
        steps = max(self.env_steps, 1)
        return dict(steps=self.env_steps, log_ms_per_step=1e3 * self.log_seconds / steps,
                    reset_log_seconds=self.reset_log_seconds,
                    env_ms_per_step=1e3 * self.env_seconds / steps,
                    log_share_of_env_step=self.log_seconds / max(self.env_seconds, 1e-9))

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()  # also on an exception or Ctrl-C: the file gets its footer
        return False

    def _close_file(self):
        """Write what is pending and the file's footer. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._log_pending_mask()
            self._finish_episodes("interrupted")
        finally:
            self.stream.flush()
            self.stream.disconnect()  # drops the file sink: writes the footer

    def _scene(self, i: int):
        """(segmentation classes, object positions, labels, colours) of env i; see `_scene_classes`."""
        raise NotImplementedError

    # ------------------------------------------------------------------ logging
    def _at(self, i: int):
        self.stream.set_time("step", sequence=self.step_count)
        self.stream.set_time("episode", sequence=int(self.episode[i]))

    def _log_episode_start(self, obs, env_ids):
        """Per env starting an episode: the objects' names as segmentation classes, their positions, the
        camera's intrinsics and the target image."""
        params = obs["sensor_param"]["hand_camera"]
        intrinsics = _numpy(params["intrinsic_cv"])
        height, width = obs["sensor_data"]["hand_camera"]["rgb"].shape[-3:-1]
        target_images = _numpy(obs["extra"]["target_image"]) if "target_image" in obs.get("extra", {}) else None
        for i in env_ids:
            self.episode[i] += 1
            self._episodes[i] = dict(ret=0.0, steps=0, first_success=None, path=[], done=False)
            self._at(i)
            classes, positions, labels, colors = self._scene(i)
            self.stream.log(f"world/env{i}", rr.AnnotationContext(classes))
            if positions is not None:
                self.stream.log(f"world/env{i}/objects", rr.Points3D(positions, labels=labels, colors=colors, radii=0.03))
            self.stream.log(f"world/env{i}/camera/image", rr.Pinhole(
                image_from_camera=intrinsics[i], resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.15))
            if target_images is not None:
                self.stream.log(f"env{i}/target_image", rr.Image(target_images[i]))
            self.stream.log(f"env{i}/outcome", rr.TextLog(f"episode {self.episode[i]} starts", level="INFO"))

    def _log_observation(self, obs, info):
        camera = obs["sensor_data"]["hand_camera"]
        rgb = _numpy(camera["rgb"])
        if rgb.ndim != 4 or len(rgb) != self.num_envs:
            raise ValueError(f"the recorder needs batch-first observations (N={self.num_envs}, H, W, 3), got rgb of "
                             f"shape {rgb.shape}: put RerunRecorder inside CPUGymWrapper, or use RerunVectorRecorder")
        segmentation = _numpy(camera["segmentation"])[..., 0] if "segmentation" in camera else None
        extrinsics = _numpy(obs["sensor_param"]["hand_camera"]["extrinsic_cv"])
        boxes = _numpy(info["target_bbox"]) if "target_bbox" in info else None
        height, width = rgb.shape[1:3]
        for i in range(self.num_envs):
            self._at(i)
            cam = f"world/env{i}/camera"
            rotation = extrinsics[i, :, :3].T  # world-from-camera (OpenCV axes: right, down, forward)
            centre = -rotation @ extrinsics[i, :, 3]
            self.stream.log(cam, rr.Transform3D(translation=centre, mat3x3=rotation))
            image = rr.Image(rgb[i])
            self.stream.log(f"{cam}/image/rgb", image.compress(jpeg_quality=self.jpeg_quality) if self.image_format == "jpeg" else image)
            if segmentation is not None:
                ids = segmentation[i].astype(np.uint8 if segmentation.max() < 256 else np.uint16)
                self.stream.log(f"{cam}/image/segmentation", rr.SegmentationImage(ids, opacity=0.5))
            if boxes is not None:
                self.stream.log(f"{cam}/image/target_box", _box(boxes[i], width, height, "ground truth", TARGET_COLOR))
            path = self._episodes[i]["path"]
            if not self._episodes[i]["done"]:
                path.append(centre)
            self.stream.log(f"world/env{i}/ee_path", rr.LineStrips3D([np.array(path)], colors=[(255, 160, 0)], radii=0.004))
        if self.mask_source is not None:
            self._pending_mask = (self.step_count, self.episode.copy(), width, height)

    def _log_step(self, action, reward, terminated, truncated, info, env_ids):
        """The transition of each env in env_ids (the others' observations start a new episode)."""
        actions = _numpy(action).reshape(self.num_envs, -1)
        reward = _numpy(reward).reshape(self.num_envs)
        success = _numpy(info["success"]).reshape(self.num_envs)
        fraction = _numpy(info["target_fraction"]).reshape(self.num_envs) if "target_fraction" in info else None
        refused = _numpy(info["refused"]).reshape(self.num_envs) if "refused" in info else np.zeros(self.num_envs, bool)
        done = _numpy(terminated).reshape(self.num_envs) | _numpy(truncated).reshape(self.num_envs)
        for i in env_ids:
            episode = self._episodes[i]
            if episode["done"]:  # ManiSkill keeps stepping finished envs of a batch until the next reset
                continue
            self._at(i)
            episode["steps"] += 1
            episode["ret"] += float(reward[i])
            if success[i] and episode["first_success"] is None:
                episode["first_success"] = episode["steps"]
            name = _action_name(actions[i])
            self.stream.log(f"env{i}/action", rr.TextLog(name + (" (refused)" if refused[i] else ""), level="DEBUG"))
            self.stream.log(f"env{i}/reward", rr.Scalars(float(reward[i])))
            self.stream.log(f"env{i}/success", rr.Scalars(float(success[i])))
            if fraction is not None:
                self.stream.log(f"env{i}/target_fraction", rr.Scalars(float(fraction[i])))
            if done[i]:
                self._log_outcome(i, bool(success[i]), fraction[i] if fraction is not None else None, "ended")
        return done

    def _log_outcome(self, i, success_now, fraction, how):
        episode = self._episodes[i]
        episode["done"] = True
        first = episode["first_success"]
        text = (f"episode {self.episode[i]} {how} after {episode['steps']} steps: "
                f"{'success' if success_now else 'no success'} at the end, "
                f"{'first success at step ' + str(first) if first else 'never successful'}, return {episode['ret']:.3f}"
                + (f", final target share {float(fraction):.3f}" if fraction is not None else ""))
        self.stream.log(f"env{i}/outcome", rr.TextLog(text, level="INFO" if success_now else "WARN"))

    def _finish_episodes(self, how):
        for i, episode in enumerate(self._episodes):
            if episode is not None and not episode["done"]:
                self._at(i)
                self._log_outcome(i, False, None, how)

    def _log_pending_mask(self):
        """The mask of the last observation: a `BoxState` outside this recorder computes it after the
        observation has passed through here, so it is logged (at that observation's time) on the next call."""
        if self._pending_mask is None:
            return
        step, episodes, width, height = self._pending_mask
        self._pending_mask = None
        mask = getattr(self.mask_source, "last_mask", None)
        if mask is None:
            return
        start = time.perf_counter()
        mask = torch.as_tensor(mask).reshape(self.num_envs, height, width).cpu()
        boxes = mask_to_box(mask).numpy()
        mask = mask.numpy()
        source = getattr(self.mask_source, "source", "box_state")
        self.stream.set_time("step", sequence=step)
        for i in range(self.num_envs):
            self.stream.set_time("episode", sequence=int(episodes[i]))
            entity = f"world/env{i}/camera/image/{source}_mask"
            if not self._mask_context_logged:
                self.stream.log(entity, rr.AnnotationContext([(0, "background", (0, 0, 0, 0)), (1, f"{source} mask", MASK_COLOR)]), static=True)
            self.stream.log(entity, rr.SegmentationImage(mask[i].astype(np.uint8), opacity=0.4))
            self.stream.log(f"{entity}_box", _box(boxes[i], width, height, f"{source} box", MASK_COLOR))
        self._mask_context_logged = True
        self.log_seconds += time.perf_counter() - start


class RerunRecorder(_Recording, gym.Wrapper):
    """Log every `reset` and `step` of a ManiSkill env (batched or not, possibly wrapped, e.g. in
    `DiscreteDirections`) to a Rerun file; see the module docstring.

    path: the `.rrd` file (its folder is created; an unwritable path fails here, before any rollout).
    image_format: "jpeg" (default, ~10x smaller) or "raw" for the wrist RGB.
    jpeg_quality: 1-100.
    """

    def __init__(self, env: gym.Env, path: str, image_format: str = "jpeg", jpeg_quality: int = 90,
                 application_id: str = "mani_active_vision"):
        gym.Wrapper.__init__(self, env)
        self.num_envs = env.unwrapped.num_envs
        self._setup(path, image_format, jpeg_quality, application_id)

    def reset(self, **kwargs):
        return self._logged_reset(**kwargs)

    def step(self, action):
        (obs, reward, terminated, truncated, info), stepped = self._timed_env_step(action)
        self._log_step(action, reward, terminated, truncated, info, range(self.num_envs))
        self._log_observation(obs, info)
        self.log_seconds += time.perf_counter() - stepped
        return obs, reward, terminated, truncated, info

    def close(self):
        """Write what is pending and the file's footer, then close the env. Safe to call twice."""
        try:
            self._close_file()
        finally:
            gym.Wrapper.close(self)

    def _scene(self, i):
        return _scene_classes(self.env.unwrapped, i)


class RerunVectorRecorder(_Recording, gym.vector.VectorWrapper):
    """The same recording for a gymnasium vector env whose sub-envs return ManiSkill's observation dict
    (e.g. `AsyncVectorEnv` of `CPUGymWrapper` envs): obs and info come stacked (N, ...) as numpy. Sub-envs
    reset automatically in gymnasium's default NEXT_STEP mode: the step after an episode's end brings the
    next episode's first observation, which starts that env's next `episode` here. Segmentation classes
    name only the target (the other objects' ids stay in the sub-env processes); no object positions."""

    def __init__(self, env: gym.vector.VectorEnv, path: str, image_format: str = "jpeg", jpeg_quality: int = 90,
                 application_id: str = "mani_active_vision"):
        gym.vector.VectorWrapper.__init__(self, env)
        mode = env.metadata.get("autoreset_mode", gym.vector.AutoresetMode.NEXT_STEP)
        if mode != gym.vector.AutoresetMode.NEXT_STEP:
            raise ValueError(f"autoreset_mode={mode!r} is not supported; use {gym.vector.AutoresetMode.NEXT_STEP!r}")
        self._setup(path, image_format, jpeg_quality, application_id)
        self._restarting = np.zeros(self.num_envs, bool)
        self._names = self._target_ids = None

    def reset(self, **kwargs):
        self._names = self._target_ids = None  # new scenes in every sub-env
        self._restarting[:] = False
        return self._logged_reset(**kwargs)

    def step(self, actions):
        (obs, reward, terminated, truncated, info), stepped = self._timed_env_step(actions)
        restarted = np.flatnonzero(self._restarting)
        self._names = self._target_ids = None
        if len(restarted):
            self._log_episode_start(obs, restarted)
        done = self._log_step(actions, reward, terminated, truncated, info, np.flatnonzero(~self._restarting))
        self._restarting = done & ~self._restarting
        self._log_observation(obs, info)
        self.log_seconds += time.perf_counter() - stepped
        return obs, reward, terminated, truncated, info

    def close(self, **kwargs):
        try:
            self._close_file()
        finally:
            gym.vector.VectorWrapper.close(self, **kwargs)

    def _scene(self, i):
        if self._names is None:  # one round trip to the sub-envs per batch of episode starts
            self._names = self.env.get_attr("object_names")
            self._target_ids = self.env.get_attr("target_seg_id")
        classes = [(0, "background", (0, 0, 0, 0)),
                   (int(_numpy(self._target_ids[i]).reshape(-1)[0]), f"target: {self._names[i][0][0]}", TARGET_COLOR)]
        return classes, None, None, None


def record_rollouts(env: gym.Env, policy, episodes: int, seed: int = 0, progress: bool = True) -> list[dict]:
    """Run `policy` for `episodes` episodes in `env` (which contains a recorder); returns per episode and
    env: steps, return, success at the end. The recorder logs; this is the plain loop.

    Ctrl-C stops it after the step in progress (raising KeyboardInterrupt), so that the last step is
    logged whole; a second Ctrl-C interrupts at once."""
    from tqdm import trange

    num_envs = env.unwrapped.num_envs
    results = []
    with _stop_on_ctrl_c() as stop_requested:
        for episode in trange(episodes, desc="episodes", disable=not progress):
            obs, info = env.reset(seed=seed + episode)
            policy.reset(obs, info)
            done = np.zeros(num_envs, bool)
            ret = np.zeros(num_envs)
            steps = 0
            while not done.all():
                if stop_requested():
                    raise KeyboardInterrupt(f"stopped by Ctrl-C in episode {episode} after {steps} steps")
                obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
                ret += np.where(done, 0.0, _numpy(reward).reshape(-1))
                done |= (_numpy(terminated) | _numpy(truncated)).reshape(-1)
                steps += 1
            for i, success in enumerate(_numpy(info["success"]).reshape(-1)):
                results.append(dict(episode=episode, env=i, steps=steps, ret=float(ret[i]), success=bool(success)))
    return results


@contextlib.contextmanager
def _stop_on_ctrl_c():
    """Turn the first SIGINT into a request the loop checks between steps. The default KeyboardInterrupt
    is raised wherever Python happens to be, and one raised inside a `__del__` or a callback is printed
    and swallowed, so a run could go on after Ctrl-C. Only the main thread can handle signals."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    requested = []

    def handler(signum, frame):
        if requested:  # the second Ctrl-C: at once
            raise KeyboardInterrupt
        requested.append(signum)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(requested)
    finally:
        signal.signal(signal.SIGINT, previous)


def screenshots(path: str, steps: list[int], out_dir: str, timeout_s: float = 60.0, settle_tries: int = 20) -> list[str]:
    """Render the recording at `path` in a headless native viewer (software Vulkan is enough), with its
    stored blueprint, paused at each global `step`, to `out_dir/<name>_step<k>.png`; returns the PNG paths.

    Uses `rerun.experimental.ViewerClient` (rerun-sdk 0.41): spawn `rerun --headless`, open the file,
    wait until it is loaded, then move the time cursor and take screenshots until two in a row match."""
    from rerun.experimental import ViewerClient

    if not os.path.isfile(path):
        raise FileNotFoundError(f"no recording at {path!r}")
    os.makedirs(out_dir, exist_ok=True)
    with socket.socket() as probe:  # a free port, so that several viewers (or a user's own) can coexist
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    executable = os.path.join(os.path.dirname(sys.executable), "rerun")
    viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True,
                                executable_path=executable if os.path.exists(executable) else None)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                viewer.get_state()
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        viewer.open(os.path.abspath(path))
        while viewer.get_state().loading:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the viewer did not finish loading {path!r} in {timeout_s} s")
            time.sleep(0.5)
        last = viewer.get_state().recordings[0].timelines
        end = next((t.end for t in last if t.name == "step"), None)
        written = []
        name = os.path.splitext(os.path.basename(path))[0]
        for step in steps:
            if end is not None and not 0 <= step <= end:
                raise ValueError(f"step={step} is outside the recording's steps 0..{end}")
            viewer.set_time("step", sequence=int(step), play_state="paused")
            # The viewer fetches chunks on demand after loading the index: shoot until the picture settles.
            image, previous = viewer.take_screenshot(), None
            for _ in range(settle_tries):
                if image == previous:
                    break
                time.sleep(0.5)
                image, previous = viewer.take_screenshot(), image
            for view in viewer.get_state().views:  # what the viewer could not show, e.g. a missing pinhole
                for report in view.reports:
                    warnings.warn(f"step {step}, view {view.name!r}: {report.severity}: {report.summary}")
            png = os.path.abspath(os.path.join(out_dir, f"{name}_step{step}.png"))
            with open(png, "wb") as f:
                f.write(image)
            written.append(png)
        return written
    finally:
        viewer.quit()


# ---------------------------------------------------------------------- helpers
def _numpy(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return np.asarray(x)


def _action_name(action: np.ndarray) -> str:
    if action.size == 1 and np.issubdtype(action.dtype, np.integer) and 0 <= int(action[0]) < len(DIRECTIONS):
        return DIRECTIONS[int(action[0])]
    return np.array2string(action, precision=3)


def _box(box, width, height, label, color) -> rr.Boxes2D:
    x, y, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0:  # nothing seen: an empty batch, so the previous box does not linger
        return rr.Boxes2D(mins=np.zeros((0, 2)), sizes=np.zeros((0, 2)))
    return rr.Boxes2D(mins=[[x * width, y * height]], sizes=[[w * width, h * height]], labels=[label], colors=[color],
                      show_labels=False)


def _scene_classes(base, i: int):
    """Segmentation classes of env i (id, label, colour) from the task's objects and ManiSkill's
    `segmentation_id_map`, and the objects' positions, labels and colours for the 3D view."""
    classes = [(0, "background", (0, 0, 0, 0))]
    for seg_id, thing in getattr(base, "segmentation_id_map", {}).items():
        name = getattr(thing, "name", "")
        if type(thing).__name__ == "Link":
            classes.append((int(seg_id), f"robot {name}", ROBOT_COLOR))
        elif name == "ground":
            classes.append((int(seg_id), "ground", GROUND_COLOR))
    objects = getattr(base, "objects", None)
    if objects is None:
        return classes, None, None, None
    names = base.object_names[i]
    labels = [f"target: {names[0]}"] + [f"distractor {k}: {names[k]}" for k in range(1, len(names))]
    colors = [TARGET_COLOR] + [DISTRACTOR_COLORS[(k - 1) % len(DISTRACTOR_COLORS)] for k in range(1, len(names))]
    for obj, label, color in zip(objects, labels, colors):
        classes.append((int(obj.per_scene_id[i]), label, color))
    positions = np.stack([_numpy(obj.pose.p[i]) for obj in objects])
    return classes, positions, labels, colors
