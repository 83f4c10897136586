"""Training data for the one-shot segmentation FCN, rendered from `ActiveVisionFind-v0` itself.

One sample = (wrist view rgb (H, W, 3) uint8, the episode's target image (h, w, 3) uint8, the target's mask
(H, W) bool). For every scene (a reset: new objects, new layout; distractors that share the target's
colour or shape come from the task) the camera is put at `views_per_scene` poses of the orbit rule (the
same family of poses the controller reaches: looking outward, 60° down), spread over the reachable set:
- "target":     aimed at a point near the target (it is in view in most of these, sometimes cut by the border);
- "distractor": aimed near another object (the target is often absent: negatives that look alike);
- "anywhere":   a random reachable pose;
- "lookalike":  aimed near a distractor that shares the target's colour or shape (else any distractor), from
                any height: hard negatives (as in DaSiamRPN), the views where a model that matches colour
                alone marks the wrong object.
The arm is set straight to the pose's joint positions (exact closed-form IK), so no physics steps are
needed. Deterministic by seed: scene k is reset with `seed + k` and its poses come from `(seed, k)`.

Stored as shards (`shard_00000.npz`, ... with arrays `scene`, `target`, `mask`, `scene_seed`, `view_mode`)
and a `manifest.json` (config, counts, share of samples with the target, seconds it took).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import time
from dataclasses import asdict, dataclass

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.objects import OBJECT_SETS
from mani_active_vision.occluders import points_inside
from mani_active_vision.robots.iiwa import CAMERA_PITCH
from mani_active_vision.robots.orbit_controller import OrbitEEPosControllerConfig, camera_end, solve_ik
from mani_active_vision.threads import WorkerThreads, use_worker_threads, worker_threads

VIEW_MODES = ("target", "distractor", "anywhere", "lookalike")


@dataclass(frozen=True)
class SegmentationDataConfig:
    object_set: str = "train"
    num_scenes: int = 50
    views_per_scene: int = 20
    image_size: int = 64
    """side of the wrist view (the env's `hand_camera` width = height)"""
    num_objects: int = 5
    seed: int = 0
    view_mode_probs: tuple[float, ...] = (0.65, 0.2, 0.15, 0.0)
    """probabilities of the VIEW_MODES (the first shipped weights' data: no "lookalike" views)"""
    height_range: tuple[float, float] = (0.12, 1.0)
    """camera (link 7) height range (m), sampled log-uniformly (close-ups are what zooming in sees);
    the controller's workspace is 0.10-1.05"""
    aim_jitter: float = 0.35
    """std of the aim point's offset from the object, as a fraction of the camera height (m per m)"""
    occluders: int = 0
    """the task's panels per scene (partly occluded targets; views with the camera in a panel are redrawn)"""

    def __post_init__(self):
        if self.object_set not in OBJECT_SETS:
            raise ValueError(f"object_set={self.object_set!r} is not one of: {', '.join(OBJECT_SETS)}")
        if self.image_size % 8:
            raise ValueError(f"image_size={self.image_size} must be a multiple of 8 (the FCN downsamples 8x)")
        if len(self.view_mode_probs) != len(VIEW_MODES) or abs(sum(self.view_mode_probs) - 1) > 1e-6:
            raise ValueError(
                f"view_mode_probs={self.view_mode_probs} must be {len(VIEW_MODES)} probabilities summing to 1"
            )


def make_data_env(config: SegmentationDataConfig) -> gym.Env:
    """The env a data set is rendered from (rgb + segmentation at `image_size`², CPU renderer)."""
    env_config = EnvConfig(
        start_pose="search",
        num_objects=config.num_objects,
        object_set=config.object_set,
        image_size=config.image_size,
        occluders=config.occluders,
    )
    return gym.make(ENV_ID, **env_config.task_kwargs())


def sample_camera_position(
    rng: np.random.Generator,
    object_xy: np.ndarray,
    config: SegmentationDataConfig,
    lookalikes: tuple[int, ...] = (),
    panels: torch.Tensor | None = None,
) -> tuple[np.ndarray, str, np.ndarray]:
    """A reachable camera (link 7) position (3,), its view mode and its joint positions (7,).

    `object_xy` (K, 2): the objects' floor positions, row 0 the target; `lookalikes`: the rows of the
    distractors that share the target's colour or shape (what "lookalike" views aim at); `panels` (1, P, 3):
    the task's occluders, which the camera end of the arm keeps out of (as the controller does).
    """
    controller = OrbitEEPosControllerConfig  # its workspace bounds (class defaults)
    mode = VIEW_MODES[rng.choice(len(VIEW_MODES), p=config.view_mode_probs)]
    for _ in range(200):
        z = math.exp(rng.uniform(*np.log(config.height_range)))
        if mode == "anywhere":
            radius, azimuth = rng.uniform(controller.min_radius, controller.max_radius), rng.uniform(-math.pi, math.pi)
        else:
            if mode == "target" or len(object_xy) == 1:
                k = 0
            elif mode == "lookalike" and lookalikes:
                k = lookalikes[rng.integers(len(lookalikes))]
            else:
                k = rng.integers(1, len(object_xy))
            aim = object_xy[k] + rng.normal(0, config.aim_jitter * z, size=2)
            # The optical axis, pitched down by CAMERA_PITCH, meets the floor z / tan(pitch) in front of the camera.
            radius = np.linalg.norm(aim) - z / math.tan(CAMERA_PITCH)
            azimuth = math.atan2(aim[1], aim[0])
        pos = np.array([radius * math.cos(azimuth), radius * math.sin(azimuth), z])
        qpos, ok = solve_ik(torch.tensor(pos[None], dtype=torch.float32), CAMERA_PITCH)
        reachable = (
            bool(ok[0])
            and controller.min_radius <= radius <= controller.max_radius
            and float(qpos[0, 3]) <= controller.max_elbow
        )
        if reachable and panels is not None and panels.shape[1]:
            reachable = not bool(
                points_inside(camera_end(torch.tensor(pos[None], dtype=torch.float32), CAMERA_PITCH), panels).any()
            )
        if reachable:
            return pos, mode, qpos[0].numpy()
    raise RuntimeError(f"no reachable camera pose found for mode {mode!r} near objects {object_xy.tolist()}")


def render_scene_views(
    env: gym.Env, scene_seed: int, rng: np.random.Generator, config: SegmentationDataConfig
) -> dict[str, np.ndarray]:
    """Reset `env` with `scene_seed` and render `views_per_scene` samples from poses drawn with `rng`.

    The arm is left where the last view put it, off the controller's target: reset `env` before stepping it."""
    obs, _ = env.reset(seed=scene_seed)
    base = env.unwrapped
    target_image = obs["extra"]["target_image"][0].cpu().numpy()
    object_xy = np.stack([obj.pose.p[0, :2].cpu().numpy() for obj in base.objects])
    target_id = base.target_seg_id[0]
    names, colors = base.object_names[0], base.object_colors[0]
    lookalikes = tuple(k for k in range(1, len(names)) if names[k] == names[0] or np.allclose(colors[k], colors[0]))
    scenes, masks, modes = [], [], []
    for _ in range(config.views_per_scene):
        _, mode, qpos = sample_camera_position(rng, object_xy, config, lookalikes, base.panel_layout())
        base.agent.robot.set_qpos(torch.as_tensor(qpos)[None])
        base.forget_view()
        images = base._hand_camera_images()
        scenes.append(images["rgb"][0].cpu().numpy())
        masks.append((images["segmentation"][0, ..., 0] == target_id).cpu().numpy())
        modes.append(VIEW_MODES.index(mode))
    n = config.views_per_scene
    return dict(
        scene=np.stack(scenes),
        target=np.repeat(target_image[None], n, 0),
        mask=np.stack(masks),
        scene_seed=np.full(n, scene_seed, dtype=np.int64),
        view_mode=np.array(modes, dtype=np.int8),
    )


def render_shard(
    env: gym.Env, out_dir: str, config: SegmentationDataConfig, index: int, scenes_per_shard: int, on_scene=None
) -> dict:
    """Render shard `index` (scenes `index * scenes_per_shard` ...) into `out_dir`; returns its manifest entry.

    A shard depends only on (config, index): shards made by different processes are the same as made by one."""
    first = index * scenes_per_shard
    parts = []
    for k in range(first, min(first + scenes_per_shard, config.num_scenes)):
        parts.append(render_scene_views(env, config.seed + k, np.random.default_rng([config.seed, k]), config))
        if on_scene is not None:
            on_scene()
    shard = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    name = f"shard_{index:05d}.npz"
    np.savez_compressed(os.path.join(out_dir, name), **shard)
    return dict(
        file=name,
        num_samples=len(shard["mask"]),
        num_scenes=len(parts),
        with_target=int(shard["mask"].any((1, 2)).sum()),
        target_pixels=int(shard["mask"].sum()),
    )


_worker_env = None


def _init_worker(config: SegmentationDataConfig, threads: WorkerThreads) -> None:
    global _worker_env
    use_worker_threads(threads)  # before the env makes the renderer (mani_active_vision.threads)
    _worker_env = make_data_env(config)


def _render_shard_in_worker(job: tuple) -> dict:
    return render_shard(_worker_env, *job)


def collect_segmentation_data(
    out_dir: str, config: SegmentationDataConfig, scenes_per_shard: int = 50, workers: int = 1, progress: bool = True
) -> dict:
    """Render a data set into `out_dir` (shards + manifest.json) with `workers` processes; returns the manifest.

    The data do not depend on `workers` (each shard is rendered from its own scene seeds)."""
    if workers < 1:
        raise ValueError(f"workers={workers} must be at least 1")
    os.makedirs(out_dir, exist_ok=True)
    num_shards = math.ceil(config.num_scenes / scenes_per_shard)
    start = time.time()
    with tqdm(total=config.num_scenes, desc=f"render {config.object_set}", unit="scene", disable=not progress) as bar:
        if workers == 1:
            env = make_data_env(config)
            try:
                shards = [
                    render_shard(env, out_dir, config, i, scenes_per_shard, on_scene=lambda: bar.update(1))
                    for i in range(num_shards)
                ]
            finally:
                env.close()
        else:
            jobs = [(out_dir, config, i, scenes_per_shard) for i in range(num_shards)]
            shards = []
            with multiprocessing.get_context("spawn").Pool(
                workers, _init_worker, (config, worker_threads(workers))
            ) as pool:
                for shard in pool.imap(_render_shard_in_worker, jobs):  # in order: the manifest lists shards by index
                    shards.append(shard)
                    bar.update(shard["num_scenes"])
    num_samples = sum(s["num_samples"] for s in shards)
    manifest = dict(
        config=asdict(config),
        shards=[dict(file=s["file"], num_samples=s["num_samples"]) for s in shards],
        num_samples=num_samples,
        share_with_target=sum(s["with_target"] for s in shards) / max(num_samples, 1),
        target_pixel_share=sum(s["target_pixels"] for s in shards) / max(num_samples * config.image_size**2, 1),
        seconds=round(time.time() - start, 1),
        workers=workers,
    )
    with open(os.path.join(out_dir, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=2)
    return manifest


def load_segmentation_data(data_dir: str) -> dict[str, np.ndarray]:
    """All shards of a data set written by `collect_segmentation_data`, concatenated."""
    path = os.path.join(data_dir, "manifest.json")
    if not os.path.exists(path):
        raise FileNotFoundError(
            f"no manifest.json in {data_dir!r}: make the data set with baselines/collect_segmentation_data.py"
        )
    with open(path) as f:
        manifest = json.load(f)
    parts = [dict(np.load(os.path.join(data_dir, shard["file"]))) for shard in manifest["shards"]]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def load_segmentation_sets(data_dirs: list[str]) -> dict[str, np.ndarray]:
    """`scene`, `target` and `mask` of several data sets (e.g. aimed views and rollout frames) concatenated, at
    the first set's scene size: a set with larger scenes (a whole multiple) is area-downsampled to it, as
    `OneShotFCN.predict` downsamples such frames, and its masks by majority of each block."""
    parts = [load_segmentation_data(data_dirs[0])]
    size, target_size = parts[0]["scene"].shape[1], parts[0]["target"].shape[1]
    for data_dir in data_dirs[1:]:
        data = load_segmentation_data(data_dir)
        factor = data["scene"].shape[1] // size
        if data["scene"].shape[1] != factor * size or data["target"].shape[1] != target_size:
            raise ValueError(
                f"{data_dir!r}: scenes {data['scene'].shape[1]}² and targets {data['target'].shape[1]}² do not fit "
                f"{data_dirs[0]!r}'s {size}² (or a whole multiple) and {target_size}²"
            )
        if factor > 1:
            blocks = (len(data["scene"]), size, factor, size, factor)
            scene = data["scene"].reshape(*blocks, 3).astype(np.float32).mean((2, 4))
            data = dict(
                scene=np.round(scene).astype(np.uint8),
                target=data["target"],
                mask=data["mask"].reshape(blocks).mean((2, 4)) >= 0.5,
            )
        parts.append(data)
    return {key: np.concatenate([p[key] for p in parts]) for key in ("scene", "target", "mask")}
