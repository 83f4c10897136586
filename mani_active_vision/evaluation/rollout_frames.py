"""Frames from rollouts of the project's policies: the distribution control acts on, to judge vision by.

The FCN's own test sets are poses aimed at the target; a policy sees something else (the sweep's far,
empty views, close-ups, look-alikes in view without the target). Each source runs a policy on a box
(`SOURCES`) from a start pose, and every `frame_stride`-th observation is kept with:
- `scene` (H, W, 3) uint8, `target` (h, w, 3) uint8 and `mask` (H, W) bool, as in `segmentation_data`, so
  that `baselines/eval_fcn.py` evaluates these sets like the others;
- `objects` (H, W) uint8: what each pixel shows: `FLOOR` (0), object slot k as k + 1 (slot 0 the target),
  `OCCLUDER` (a panel of the task's `occluders`), `ROBOT`; and `relations` (max objects,) int8: each slot's relation to the target (`RELATIONS`), so that a
  false positive can be attributed to an identical twin, a same-shape or same-colour distractor, another
  object, or the floor and the robot;
- `source`, `scene_seed`, `step`.
Shards + `manifest.json` in the layout of `segmentation_data`; deterministic by seed (episode k of source
j is reset with `seed + 1000 j + k`).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import asdict, dataclass

import numpy as np
from tqdm import tqdm

from mani_active_vision.agents.fcn import WEIGHTS_PATH
from mani_active_vision.agents.policies import make_policy, policy_kwargs
from mani_active_vision.agents.q_network import checkpoint_env_config
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.rollout import run_episode
from mani_active_vision.json_io import save_json

SOURCES = {
    "servo_sky": ("servo", "sky", "ground_truth"),
    "explore_servo_sky": ("explore", "sky", "ground_truth"),
    "random_sky": ("random", "sky", "ground_truth"),
    "random_search": ("random", "search", "ground_truth"),
    "servo_fcn_sky": ("servo", "sky", "fcn"),
    "servo_over_sky": ("servo", "sky", "ground_truth"),
    "dqn_fcn_sky": ("explore", "sky", "fcn"),
}
"""source name -> (policy, start pose, box source): the scripted servo, the paper's exploration handing over
to it, and random directions from both start poses, on the ground-truth box; the servo on the shipped
FCN's box, which approaches whatever the FCN marks (hard negatives mined by the model: close-ups of the
look-alikes it mistakes for the target); and, for scenes with occluders, the servo that looks over the panels
(`LOOKS_OVER`), which comes up to targets a panel partly hides; and the shipped DQN as deployed (`DEPLOYED_DQN`:
the exploration handing over to it, in its checkpoint's env on the FCN's box), which walks up to the look-alikes
the deployed agent takes up. The test set uses the first four."""
LOOKS_OVER = ("servo_over_sky",)
"""the sources whose servo looks over the panels and approaches from above (`ServoPolicy(look_over=True)`)"""
DEPLOYED_DQN = {"dqn_fcn_sky": os.path.join(os.path.dirname(WEIGHTS_PATH), "dqn.pt")}
"""the sources that run the exploration handing over to a DQN (the shipped `agents/weights/dqn.pt`), as it is
deployed: its checkpoint's env config, with the collection's object set, image size, occluders and FCN weights"""
RELATIONS = ("target", "identical twin", "same shape", "same colour", "other object")
FLOOR, OCCLUDER, ROBOT = 0, 254, 255


@dataclass(frozen=True)
class RolloutFramesConfig:
    object_set: str = "unseen"
    """objects of the episodes (held-out: unseen)"""
    episodes_per_source: int = 20
    """episodes of each source"""
    frame_stride: int = 4
    """keep every n-th observation of an episode (the reset's included)"""
    image_size: int = 128
    """the wrist camera's side"""
    seed: int = 400_000
    """episode k of source j is reset with seed + 1000 j + k (held out: no FCN or DQN seed is here)"""
    sources: tuple[str, ...] = tuple(SOURCES)[:4]
    """which of SOURCES to run"""
    fcn_weights: str = ""
    """the FCN checkpoint of the sources on its box ("": the shipped agents/weights/fcn.pt)"""
    occluders: int = 0
    """the task's panels per scene (partly occluded targets)"""

    def __post_init__(self):
        unknown = [s for s in self.sources if s not in SOURCES]
        if unknown:
            raise ValueError(f"sources {unknown} are not in: {', '.join(SOURCES)}")
        if self.frame_stride < 1 or self.episodes_per_source < 1:
            raise ValueError("frame_stride and episodes_per_source must be at least 1")


def slot_relations(names: list[str], colors: list[tuple]) -> np.ndarray:
    """Each object slot's index in RELATIONS: slot 0 is the target; a distractor of the same model and colour
    is its identical twin; else same shape (model), same colour, or another object."""
    relations = []
    for k, (name, color) in enumerate(zip(names, colors)):
        same_shape, same_color = name == names[0], np.allclose(color, colors[0])
        if k == 0:
            relations.append("target")
        elif same_shape and same_color:
            relations.append("identical twin")
        else:
            relations.append("same shape" if same_shape else "same colour" if same_color else "other object")
    return np.array([RELATIONS.index(r) for r in relations], np.int8)


def object_map(base, segmentation: np.ndarray) -> np.ndarray:
    """(H, W) uint8 of what each pixel of env 0's segmentation shows: FLOOR, slot k + 1, OCCLUDER or ROBOT."""
    lookup = np.zeros(int(segmentation.max()) + 1, np.uint8)
    for seg_id, thing in base.segmentation_id_map.items():
        if type(thing).__name__ == "Link" and seg_id < len(lookup):
            lookup[seg_id] = ROBOT
    for k, obj in enumerate(base.objects):
        seg_id = int(obj.per_scene_id[0])
        if seg_id < len(lookup):
            lookup[seg_id] = k + 1
    for panel in base.panels:
        seg_id = int(panel.per_scene_id[0])
        if seg_id < len(lookup):
            lookup[seg_id] = OCCLUDER
    return lookup[segmentation]


def record_episode(env, policy, seed: int, stride: int, source: int) -> dict[str, np.ndarray]:
    """Run one episode and keep every `stride`-th frame (see the module docstring)."""
    base, frames, visible = env.unwrapped, [], []

    def keep(obs, info):
        frames.append(env.last_observation)
        visible.append(float(info["target_visible_fraction"][0]))

    run_episode(env, policy, seed, on_step=keep)
    frames, visible = frames[::stride], visible[::stride]
    relations = np.full(base.max_objects, -1, np.int8)
    relations[: base.num_objects] = slot_relations(base.object_names[0], base.object_colors[0])
    target_id = int(base.target_seg_id[0])
    scene, target, mask, objects = [], [], [], []
    for raw in frames:
        camera = raw["sensor_data"]["hand_camera"]
        segmentation = camera["segmentation"][0, ..., 0].cpu().numpy()
        scene.append(camera["rgb"][0].cpu().numpy())
        target.append(raw["extra"]["target_image"][0].cpu().numpy())
        mask.append(segmentation == target_id)
        objects.append(object_map(base, segmentation))
    n = len(frames)
    return dict(
        scene=np.stack(scene),
        target=np.stack(target),
        mask=np.stack(mask),
        objects=np.stack(objects),
        relations=np.repeat(relations[None], n, 0),
        source=np.full(n, source, np.int8),
        scene_seed=np.full(n, seed, np.int64),
        step=np.arange(n, dtype=np.int16) * stride,
        visible_fraction=np.array(visible, np.float32),
    )


def source_env_config(name: str, config: RolloutFramesConfig) -> EnvConfig:
    """The env a source runs in: the defaults, or for a `DEPLOYED_DQN` source its checkpoint's env config; with the
    collection's object set, image size and occluders, and the source's start pose and box."""
    _, start_pose, box_source = SOURCES[name]
    checkpoint = DEPLOYED_DQN.get(name, "")
    return dataclasses.replace(
        checkpoint_env_config(checkpoint) if checkpoint else EnvConfig(),
        object_set=config.object_set,
        start_pose=start_pose,
        image_size=config.image_size,
        box_source=box_source,
        fcn_weights=config.fcn_weights if box_source == "fcn" else "",
        occluders=config.occluders,
    )


def collect_rollout_frames(out_dir: str, config: RolloutFramesConfig, progress: bool = True) -> dict:
    """Render the rollout-frame set into `out_dir` (one shard per source + manifest.json); returns the manifest."""
    os.makedirs(out_dir, exist_ok=True)
    start, shards = time.time(), []
    for j, name in enumerate(config.sources):
        policy_name = SOURCES[name][0]
        source = list(SOURCES).index(name)
        checkpoint = DEPLOYED_DQN.get(name, "")
        env = make_env(source_env_config(name, config))
        try:
            if checkpoint:
                kwargs = policy_kwargs("explore", "dqn", checkpoint, seed=config.seed)
            else:
                kwargs = {"then": "servo"} if policy_name == "explore" else {}
            if name in LOOKS_OVER:
                kwargs["look_over"] = True
            policy = make_policy(policy_name, env, **kwargs)
            parts = []
            seeds = [config.seed + 1000 * source + k for k in range(config.episodes_per_source)]
            for seed in tqdm(seeds, desc=f"frames {name}", disable=not progress):
                parts.append(record_episode(env, policy, seed, config.frame_stride, source))
        finally:
            env.close()
        shard = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
        file = f"shard_{j:05d}.npz"
        np.savez_compressed(os.path.join(out_dir, file), **shard)
        shards.append(
            dict(
                file=file, num_samples=len(shard["mask"]), source=name, with_target=int(shard["mask"].any((1, 2)).sum())
            )
        )
    num_samples = sum(s["num_samples"] for s in shards)
    manifest = dict(
        config={**asdict(config), "kind": "rollout_frames"},
        shards=[dict(file=s["file"], num_samples=s["num_samples"], source=s["source"]) for s in shards],
        num_samples=num_samples,
        share_with_target=sum(s["with_target"] for s in shards) / max(num_samples, 1),
        sources=list(SOURCES),
        relations=list(RELATIONS),
        seconds=round(time.time() - start, 1),
    )
    save_json(manifest, os.path.join(out_dir, "manifest.json"))
    return manifest


def attribute_false_positives(pred: np.ndarray, data: dict) -> dict[str, int]:
    """On frames without the target where a mask `pred` (N, H, W) bool marks something: what the marked pixels
    mostly show (a distractor's relation to the target, "floor", "occluder" or "robot"); counts per kind."""
    kinds = [*RELATIONS[1:], "floor", "occluder", "robot"]
    counts = dict.fromkeys(kinds, 0)
    absent = ~data["mask"].any((1, 2))
    for i in np.flatnonzero(absent & pred.any((1, 2))):
        values, hits = np.unique(data["objects"][i][pred[i]], return_counts=True)
        value = int(values[hits.argmax()])
        if value == FLOOR:
            counts["floor"] += 1
        elif value == ROBOT:
            counts["robot"] += 1
        elif value == OCCLUDER:
            counts["occluder"] += 1
        else:
            counts[RELATIONS[int(data["relations"][i][value - 1])]] += 1
    return counts
