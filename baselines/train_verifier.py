"""Train the FCN's second stage (`agents/verifier.py`) on frames from rollouts, and save the FCN with it.

    python baselines/train_verifier.py --fcn runs/fcn_v3_paper/best.pt \
        --data-dirs data/rollout128v3/train data/rollout128v3/train2 --run-dir runs/verifier
    python baselines/train_verifier.py --init agents/weights/fcn.pt --epochs 4 --lr 3e-4 ...   # fine-tune the shipped one

The candidates are what it will see: the regions the segmentation network (`--fcn`, frozen) marks on each
rollout frame (its `verifier_regions` largest), each labelled "target" when most of its pixels lie on the
target; and, for more look-alikes and more views of targets, every object in view with at least 4 pixels
around its true box, moved and scaled a little (as a proposal would be); at the frames' 128² and
area-downsampled to 64² (`--scales`: the camera sizes the agents use). The frames' scene seeds split them:
every 10th scene is validation. Binary cross-entropy, both crops mirrored together half the time (and, with
`--rotate`, turned together). The
threshold is the one with the best accuracy on the validation frames' FCN regions; the best epoch by the
same. Augmented (`augment`) and weight-decayed: without, it learnt the training objects (validation accuracy
best after one epoch, then falling as the training loss fell). Saves `best.pt`: the FCN's checkpoint with `verifier_crop` set and the verifier's weights.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
import tyro
from tqdm import tqdm

from mani_active_vision.agents.fcn import (
    OneShotFCN,
    load_checkpoint,
    normalize_images,
    save_checkpoint,
    target_pixels,
)
from mani_active_vision.agents.verifier import candidate_crops, square_crops, target_crops
from mani_active_vision.json_io import save_json
from mani_active_vision.segmentation_data import load_segmentation_data

THRESHOLDS = tuple(round(0.05 * i, 2) for i in range(2, 19))
"""verifier thresholds tried on validation: 0.10 ... 0.90"""


@dataclass
class Args:
    fcn: str = "runs/fcn/best.pt"
    """the segmentation network the verifier sits on, without a verifier (its weights are kept as they are;
    default: the one scripts/make_fcn.sh trains)"""
    init: str = ""
    """an FCN checkpoint with a verifier (e.g. agents/weights/fcn.pt) to fine-tune instead: its network is the one
    the verifier sits on (--fcn is not read) and its verifier the starting point (tried on occluded scenes:
    docs/task.md#occluders)"""
    data_dirs: list[str] = field(default_factory=lambda: ["data/rollout128v3/train"])
    """rollout-frame sets (`baselines/collect_rollout_frames.py`: they name what each pixel shows)"""
    run_dir: str = "runs/verifier"
    crop: int = 32
    regions: int = 4
    """regions of each mask verified"""
    ground_truth_boxes: bool = True
    """also train on every object in view around its (jittered) true box"""
    scales: tuple[int, ...] = (1, 2)
    """the frames also area-downsampled by these factors (2: the 64² camera the DQN's env config uses)"""
    threshold: float = 0.0
    """the verifier threshold saved with the weights (0: the one with the best validation accuracy). The epoch
    is chosen by validation accuracy either way; a fixed bar is for control, which needs few false positives
    more than the best accuracy (docs/vision.md)"""
    cut_share: float = 0.0
    """saved as `FCNConfig.verifier_cut_share`: a region cut by the image's border and at least this share of the
    image needs only `cut_threshold` (0: off)"""
    cut_threshold: float = 0.3
    """saved as `FCNConfig.verifier_cut_threshold`"""
    rotate: float = 0.0
    """degrees: both crops of a pair also turned by one random angle up to this (0: not turned)"""
    mirror: bool = False
    """saved as `FCNConfig.verifier_mirror`: at inference each region is also scored with both crops mirrored and
    the two logits averaged (training and its validation are unchanged)"""
    epochs: int = 12
    batch_size: int = 128
    lr: float = 1e-3
    weight_decay: float = 1e-3
    seed: int = 0
    threads: int = 1


def region_targets(candidates: dict, objects: np.ndarray) -> np.ndarray:
    """1.0 for each candidate region most of whose pixels lie on the target (object slot 0), else 0.0."""
    labels = []
    for image_labels, ids, image_objects in zip(candidates["labels"], candidates["ids"], objects):
        for k in ids:
            region = image_labels == k
            labels.append(float((image_objects[region] == 1).mean() > 0.5))
    return np.array(labels, np.float32)


def object_boxes(objects: np.ndarray, rng: np.random.Generator) -> tuple[list[int], torch.Tensor, np.ndarray]:
    """(frame index, jittered pixel box (M, 4), is target (M,)) of every object slot with at least 4 pixels in
    each frame's object map (values 1..K are slots; 0 floor, 254 panel, 255 robot)."""
    frames, boxes, is_target = [], [], []
    for i, image in enumerate(objects):
        for value in np.unique(image):
            if not 1 <= value <= 250:
                continue
            mask = image == value
            if mask.sum() < 4:
                continue
            ys, xs = np.nonzero(mask)
            x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
            side = max(x1 - x0, y1 - y0)
            scale = rng.uniform(0.75, 1.25)
            dx, dy = rng.uniform(-0.15, 0.15, 2) * side
            cx, cy, hw, hh = (x0 + x1) / 2 + dx, (y0 + y1) / 2 + dy, (x1 - x0) * scale / 2, (y1 - y0) * scale / 2
            frames.append(i)
            boxes.append([cx - hw, cy - hh, cx + hw, cy + hh])
            is_target.append(float(value == 1))
    return frames, torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4), np.array(is_target, np.float32)


def downsample(data: dict, factor: int) -> dict:
    """Frames area-downsampled by `factor` (object maps: each block's top-left pixel), as a smaller camera."""
    if factor == 1:
        return data
    n, size = len(data["scene"]), data["scene"].shape[1] // factor
    scene = np.empty((n, size, size, 3), np.uint8)
    for start in range(0, n, 1000):  # in chunks: the float copy of 39,000 frames at once would be 7.7 GB
        chunk = data["scene"][start : start + 1000]
        blocks = chunk.reshape(len(chunk), size, factor, size, factor, 3).astype(np.float32).mean((2, 4))
        scene[start : start + 1000] = np.round(blocks)
    return dict(data, scene=scene, objects=data["objects"][:, ::factor, ::factor])


@torch.inference_mode()
def build_candidates(model: OneShotFCN, data: dict, args: Args, rng: np.random.Generator, batch: int = 64) -> dict:
    """Crops (float16) and labels of the FCN's regions (`fcn` = True) and of jittered true boxes (False)."""
    parts = dict(target=[], scene=[], label=[], frame=[], fcn=[])
    for start in tqdm(range(0, len(data["scene"]), batch), desc="candidates", leave=False):
        stop = min(start + batch, len(data["scene"]))
        scene_rgb, target_rgb = data["scene"][start:stop], data["target"][start:stop]
        masks = model.predict(scene_rgb, target_rgb).numpy()
        scene, target = normalize_images(torch.from_numpy(scene_rgb)), normalize_images(torch.from_numpy(target_rgb))
        targets = target_crops(target, target_pixels(target), args.crop)
        found = candidate_crops(scene, masks, args.regions, args.crop)
        region_labels = region_targets(found, data["objects"][start:stop])
        groups = [(found["image"], targets[found["image"]], found["scene_crops"], region_labels, True)]
        if args.ground_truth_boxes:
            frames, boxes, is_target = object_boxes(data["objects"][start:stop], rng)
            frames = torch.tensor(frames, dtype=torch.long)
            groups.append((frames, targets[frames], square_crops(scene[frames], boxes, args.crop), is_target, False))
        for frames, frame_targets, scene_crops, labels, from_fcn in groups:
            parts["target"].append(frame_targets.half())
            parts["scene"].append(scene_crops.half())
            parts["label"].append(torch.from_numpy(labels))
            parts["frame"].append(frames + start)
            parts["fcn"].append(torch.full((len(frames),), from_fcn))
    return {k: torch.cat(v) for k, v in parts.items()}


def augment(
    target: torch.Tensor, scene: torch.Tensor, rng: np.random.Generator, rotate: float = 0.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """What keeps "same object" from being learnt as "one of the 800 training objects": both crops get the
    same mirror, the same permutation of the colour channels and the same brightness (so the pair stays a
    pair of one object or of two), and the candidate's crop a shift of up to 2 px (as a proposal's box
    would be off)."""
    n = len(target)
    flip = torch.from_numpy(rng.random(n) < 0.5).view(-1, 1, 1, 1)
    target, scene = torch.where(flip, target.flip(-1), target), torch.where(flip, scene.flip(-1), scene)
    order = torch.from_numpy(np.argsort(rng.random((n, 3)), 1))
    gather = order.view(n, 3, 1, 1).expand_as(target)
    target, scene = target.gather(1, gather), scene.gather(1, gather.expand_as(scene))
    gain = torch.from_numpy(rng.uniform(0.8, 1.2, (n, 1, 1, 1))).float()
    target, scene = (target + 0.5) * gain - 0.5, (scene + 0.5) * gain - 0.5
    dy, dx = rng.integers(-2, 3, 2)
    scene = torch.roll(scene, shifts=(int(dy), int(dx)), dims=(2, 3))
    if rotate:  # one turn for both crops; the corners turned in are 0, the crops' own outside value
        angle = torch.from_numpy(np.radians(rng.uniform(-rotate, rotate, n))).float()
        cos, sin, zero = angle.cos(), angle.sin(), torch.zeros(n)
        theta = torch.stack([torch.stack([cos, -sin, zero], 1), torch.stack([sin, cos, zero], 1)], 1)
        grid = F.affine_grid(theta, list(target.shape), align_corners=False)
        target, scene = (F.grid_sample(x, grid, align_corners=False) for x in (target, scene))
    return target, scene


def accuracy_by_threshold(logits: torch.Tensor, labels: torch.Tensor) -> dict[float, float]:
    p = logits.sigmoid()
    return {t: float(((p >= t).float() == labels).float().mean()) for t in THRESHOLDS}


def network(args: Args) -> OneShotFCN:
    """The checkpoint training starts from: the network alone (`--fcn`), or with `--init` a network and its verifier,
    whose crop and regions must be the ones asked for."""
    if not args.init:
        fcn, _ = load_checkpoint(args.fcn)
        if fcn.config.verifier_crop:
            raise ValueError(f"{args.fcn} already has a verifier: give the segmentation network alone (or --init it)")
        return fcn
    start, _ = load_checkpoint(args.init)
    found = (start.config.verifier_crop, start.config.verifier_regions)
    if found != (args.crop, args.regions):
        asked = (args.crop, args.regions)
        raise ValueError(f"--init {args.init} has a verifier of crop, regions {found}, not --crop, --regions {asked}")
    return start


def main(args: Args):
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    if not 0 <= args.threshold < 1:
        raise ValueError(f"--threshold {args.threshold} must be in [0, 1) (0: the best on validation)")
    os.makedirs(args.run_dir, exist_ok=True)
    start = fcn = network(args)
    if args.init:  # the network alone proposes the candidates
        fcn = start.network_alone()
    sets = [load_segmentation_data(d) for d in args.data_dirs]
    for data_dir, data in zip(args.data_dirs, sets):
        if "objects" not in data:
            raise ValueError(f"{data_dir!r} is not a rollout-frame set (no object maps): collect_rollout_frames.py")
    data = {k: np.concatenate([d[k] for d in sets]) for k in ("scene", "target", "objects", "scene_seed")}
    del sets  # the frames are held once (4 sets of 9,750: ~3 GB)
    started = time.time()
    per_scale = [build_candidates(fcn, downsample(data, factor), args, rng) for factor in args.scales]
    candidates = {k: torch.cat([c[k] for c in per_scale]) for k in per_scale[0]}
    del per_scale
    val_frame = torch.from_numpy(data["scene_seed"] % 10 == 0)[candidates["frame"]]
    num_frames = len(data["scene"])
    del data  # training needs only the crops
    train_idx, val_idx = torch.nonzero(~val_frame)[:, 0], torch.nonzero(val_frame & candidates["fcn"])[:, 0]
    labels = candidates["label"]
    print(
        f"{len(labels)} candidates from {num_frames} frames at scales {args.scales} in {time.time() - started:.0f} s: train "
        f"{len(train_idx)} ({labels[train_idx].mean():.2f} target), validation (FCN regions) {len(val_idx)} "
        f"({labels[val_idx].mean():.2f} target)"
    )

    config = dataclasses.replace(
        fcn.config,
        verifier_crop=args.crop,
        verifier_regions=args.regions,
        verifier_cut_share=args.cut_share,
        verifier_cut_threshold=args.cut_threshold,
        verifier_mirror=args.mirror,
    )
    model = OneShotFCN(config)
    model.load_state_dict(start.state_dict(), strict=bool(args.init))  # a network alone lacks the verifier
    verifier = model.verifier
    optimizer = torch.optim.AdamW(verifier.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    positive = float(labels[train_idx].mean())
    pos_weight = torch.tensor((1 - positive) / max(positive, 1e-3))
    history, best = [], (-1.0, 0.5)
    steps = math.ceil(len(train_idx) / args.batch_size)
    for epoch in range(args.epochs):
        lr = args.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * epoch / args.epochs)))
        for group in optimizer.param_groups:
            group["lr"] = lr
        verifier.train()
        order = train_idx[torch.from_numpy(rng.permutation(len(train_idx)))]
        losses, epoch_started = [], time.time()
        for step in tqdm(range(steps), desc=f"epoch {epoch + 1}/{args.epochs}", leave=False):
            idx = order[step * args.batch_size : (step + 1) * args.batch_size]
            target, scene = augment(
                candidates["target"][idx].float(), candidates["scene"][idx].float(), rng, args.rotate
            )
            loss = F.binary_cross_entropy_with_logits(verifier(target, scene), labels[idx], pos_weight=pos_weight)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
        verifier.eval()
        with torch.inference_mode():
            logits = torch.cat(
                [verifier(candidates["target"][i].float(), candidates["scene"][i].float()) for i in val_idx.split(512)]
            )
        accuracy = accuracy_by_threshold(logits, labels[val_idx])
        threshold = max(accuracy, key=accuracy.get)
        history.append(
            dict(
                epoch=epoch + 1,
                lr=lr,
                train_loss=float(np.mean(losses)),
                val_accuracy=accuracy[threshold],
                threshold=threshold,
                train_seconds=round(time.time() - epoch_started, 1),
            )
        )
        print(
            f"epoch {epoch + 1:2d} lr {lr:.2e} loss {np.mean(losses):.4f} val accuracy {accuracy[threshold]:.3f} "
            f"at {threshold:.2f} (0.5: {accuracy[0.5]:.3f}) ({time.time() - epoch_started:.0f} s)"
        )
        if accuracy[threshold] > best[0]:
            best = (accuracy[threshold], threshold)
            model.config = dataclasses.replace(config, verifier_threshold=args.threshold or threshold)
            save_checkpoint(os.path.join(args.run_dir, "best.pt"), model, epoch=epoch + 1, args=asdict(args))
        save_json(history, os.path.join(args.run_dir, "history.json"))
    saved = args.threshold or best[1]
    print(
        f"best validation accuracy {best[0]:.3f} at threshold {best[1]:.2f}, saved with threshold {saved:.2f}: "
        f"{os.path.join(args.run_dir, 'best.pt')}"
    )


if __name__ == "__main__":
    main(tyro.cli(Args))
