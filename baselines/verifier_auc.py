"""How well does the verifier tell the target's regions from a look-alike's, by region size? On rollout frames
(`collect_rollout_frames.py`: they name each pixel's object), every candidate region of the segmentation
network (its `verifier_regions` largest) is scored by the verifier, and, for comparison, by the silhouette
IoU of the region against the target image's (`boxes.silhouette`: outline alone). ROC AUC of the target's
regions against same-colour look-alikes' and against every other region, by the region's size; and the share
of the target's regions the verifier turns away at a bar (`--bar`, the deployed track bar by default; the
checkpoint's lower bar for large regions cut by the border where it has one), apart for targets cut by the
image's border and whole ones, and the share of other regions it accepts.

    python baselines/verifier_auc.py --weights agents/weights/fcn.pt --data-dir data/rollout128/test_unseen
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import tyro
from tqdm import tqdm

from mani_active_vision.agents.fcn import OneShotFCN, load_checkpoint, normalize_images, target_pixels
from mani_active_vision.agents.verifier import candidate_crops, cut_regions
from mani_active_vision.boxes import roc_auc, silhouette, silhouette_iou, target_stats
from mani_active_vision.envs import DQN_FCN_THRESHOLDS
from mani_active_vision.evaluation.rollout_frames import RELATIONS
from mani_active_vision.segmentation_data import load_segmentation_data

SIZE_BINS = (1, 20, 100, 400, 1600, 10**9)
"""edges of a region's size, pixels"""


@dataclass
class Args:
    weights: str = "agents/weights/fcn.pt"
    """an FCN checkpoint with a verifier"""
    data_dir: str = "data/rollout128/test_unseen"
    bar: float = DQN_FCN_THRESHOLDS[1]
    """the verifier probability a region needs (the deployed track bar; the acquire bar is higher)"""


@torch.inference_mode()
def region_scores(model: OneShotFCN, network: OneShotFCN, data: dict, batch: int = 64) -> dict[str, np.ndarray]:
    """Per candidate region of `network`: size, what it lies on ("target" or a relation, "floor or robot"),
    `model`'s verifier probability, silhouette IoU, whether the frame's target touches the image's border, and
    whether the region is large and cut by it, so that `model` asks only its cut bar (`verifier.cut_regions`)."""
    crop, cut_share = model.config.verifier_crop, model.config.verifier_cut_share
    rows = dict(size=[], kind=[], probability=[], silhouette=[], cut=[], cut_region=[])
    for start in tqdm(range(0, len(data["scene"]), batch), desc="regions", leave=False):
        scene_rgb, target_rgb = data["scene"][start : start + batch], data["target"][start : start + batch]
        masks = network.predict(scene_rgb, target_rgb, runtime="torch").numpy()
        cut = target_stats(torch.from_numpy(data["mask"][start : start + batch]))["touches_border"].tolist()
        scene, target = normalize_images(torch.from_numpy(scene_rgb)), normalize_images(torch.from_numpy(target_rgb))
        found = candidate_crops(scene, masks, model.config.verifier_regions, crop)
        if not len(found["image"]):
            continue
        pixels = target_pixels(target)
        probability = model.candidate_logits(target, found, runtime="torch").sigmoid()
        rows["probability"] += probability.tolist()
        rows["cut_region"] += (
            cut_regions(found, masks.shape[1:], cut_share)
            if cut_share
            else torch.zeros(len(found["image"]), dtype=bool)
        ).tolist()
        for i, (labels, ids) in enumerate(zip(found["labels"], found["ids"])):
            objects, relations = data["objects"][start + i], data["relations"][start + i]
            picture = silhouette(pixels[i].numpy())
            for k in ids:
                region = labels == k
                on = int(np.bincount(objects[region], minlength=256).argmax())
                kind = RELATIONS[int(relations[on - 1])] if 1 <= on <= len(relations) else "floor or robot"
                rows["size"].append(int(region.sum()))
                rows["kind"].append(kind)
                rows["silhouette"].append(silhouette_iou(silhouette(region), picture))
                rows["cut"].append(cut[i])
    return {k: np.array(v) for k, v in rows.items()}


def main(args: Args):
    torch.set_num_threads(1)
    model, _ = load_checkpoint(args.weights)
    if not model.config.verifier_crop:
        raise ValueError(f"{args.weights} has no verifier (verifier_crop=0)")
    rows = region_scores(model.eval(), model.network_alone(), load_segmentation_data(args.data_dir))
    bar = np.where(rows["cut_region"], min(args.bar, model.config.verifier_cut_threshold), args.bar)
    print(f"{len(rows['size'])} candidate regions on {args.data_dir}, {args.weights}")
    print(
        "| region px | target | same colour | others | AUC vs same colour: verifier | silhouette | AUC vs all: verifier "
        f"| target under the bar ({args.bar}): whole | cut by the border | others over it |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for low, high in zip(SIZE_BINS[:-1], SIZE_BINS[1:]):
        sized = (rows["size"] >= low) & (rows["size"] < high)
        target, same_colour = sized & (rows["kind"] == "target"), sized & (rows["kind"] == "same colour")
        others = sized & ~target
        cells = [
            roc_auc(rows["probability"][target], rows["probability"][same_colour]),
            roc_auc(rows["silhouette"][target], rows["silhouette"][same_colour]),
            roc_auc(rows["probability"][target], rows["probability"][others]),
        ]
        under = rows["probability"] < bar
        shares = [share(under[target & (rows["cut"] == cut)]) for cut in (False, True)] + [share(~under[others])]
        print(
            f"| {low}–{high if high < 10**9 else '∞'} | {target.sum()} | {same_colour.sum()} | {others.sum()} | "
            + " | ".join(f"{c:.3f}" for c in cells)
            + " | "
            + " | ".join(shares)
            + " |"
        )


def share(flags: np.ndarray) -> str:
    """The share of true `flags` and their count, "0.42 (252)"; "–" without any."""
    return f"{flags.mean():.2f} ({len(flags)})" if len(flags) else "–"


if __name__ == "__main__":
    main(tyro.cli(Args))
