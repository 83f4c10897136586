"""Evaluate FCN weights on segmentation data sets (train-object and unseen-object test splits): a markdown table.

  python baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs data/seg64/test_train data/seg64/test_unseen

Columns: pixel accuracy (all samples); target IoU, mean per sample over samples that contain the target
(and pooled: summed intersections / summed unions); FP rate = share of samples without the target where
the model marks any pixel; box error = mean |Δ| of the normalised (x, y, w, h) box on samples with the
target; miss rate = share of those where the mask is empty. IoU (≥1%): target IoU over samples where the
target covers at least 1% of the image (the sizes control works with; tiny far-away targets of a few
pixels are where per-sample IoU is lowest); IoU (≥20 px): over samples with at least 20 target pixels. A
second table splits the target IoU by the target's share of the image. Rollout-frame sets
(`baselines/collect_rollout_frames.py`) also get a table of what the false positives on target-absent
frames lie on (an identical twin, a same-shape or same-colour distractor, another object, floor, a panel, robot)
and the same metrics per source policy, and, for scenes with occluders, the target IoU on frames where a
panel hides part of the target beside those where none does.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import tyro

from mani_active_vision.agents.fcn import (
    WEIGHTS_PATH,
    dataset_counts,
    load_checkpoint,
    segmenting_at,
    summarize_counts,
)
from mani_active_vision.evaluation.rollout_frames import SOURCES, attribute_false_positives
from mani_active_vision.occluders import MIN_VISIBLE_FRACTION
from mani_active_vision.segmentation_data import load_segmentation_data


@dataclass
class Args:
    weights: str | None = None
    """FCN checkpoint (default: the shipped agents/weights/fcn.pt)"""
    data_dirs: list[str] = field(default_factory=lambda: ["data/seg64/test_train", "data/seg64/test_unseen"])
    """data sets written by collect_segmentation_data.py"""
    out: str = "outputs/fcn_eval.md"
    """where the markdown table is written"""
    largest_component: bool = False
    """keep only the largest connected region of each predicted mask (as BoxState does)"""
    examples_png: str | None = "outputs/fcn_examples.png"
    """a picture of examples per data set: samples with the target and false positives (none: skip)"""
    examples: int = 8
    """examples of each kind per data set in that picture"""
    presence_threshold: float | None = None
    """for a model with a presence head: the presence probability under which the mask is emptied (default:
    the checkpoint's)"""
    segment_size: int = 0
    """the side the network segments each scene at (`FCNConfig.segment_size`; 0: the checkpoint's training
    size), e.g. 128 (envs.FCN_SEGMENT_SIZE) as `EnvConfig(fcn_segment_size=128)` deploys it"""
    verifier_bars: tuple[float, ...] = ()
    """for a model with a verifier: also a table of each data set at each of these bars in place of the
    checkpoint's (e.g. 0.9 0.97, the shipped DQNs' track and acquire bars): what control meets at them"""


MIN_TARGET_PIXELS = 20
"""the "IoU (≥20 px)" columns: samples with at least this many target pixels (fewer are where IoU is noise)"""


def iou_20px(counts: dict) -> float:
    """Target IoU over the samples of `counts` (`dataset_counts`) with at least MIN_TARGET_PIXELS target pixels."""
    return summarize_counts({k: v[counts["true"] >= MIN_TARGET_PIXELS] for k, v in counts.items()})["target_iou"]


SIZE_BINS = (0.0, 0.002, 0.005, 0.01, 0.03, 0.1, 1.01)
"""edges of the target's share of the image for the IoU-by-size table"""
COLUMNS = ("pixel_accuracy", "target_iou", "pooled_target_iou", "false_positive_rate", "box_error", "miss_rate")


def plot_examples(model, datasets: dict, counts: dict, args: Args) -> None:
    """Per data set two strips of (target image above, scene with the predicted mask in magenta below): random
    samples that contain the target, then random samples without it where the model marked something."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    strips = []
    for name, data in datasets.items():
        c = counts[name]
        kinds = {
            "with the target": np.flatnonzero(c["true"] > 0),
            "false positives (no target in view)": np.flatnonzero((c["true"] == 0) & (c["predicted"] > 0)),
        }
        for kind, pool in kinds.items():
            picks = np.sort(rng.choice(pool, min(args.examples, len(pool)), replace=False))
            if not len(picks):
                continue
            overlay = data["scene"][picks].copy()
            overlay[model.predict(data["scene"][picks], data["target"][picks], args.largest_component).numpy()] = (
                255,
                0,
                255,
            )
            targets = model_sized(data["target"][picks], overlay.shape[1])
            pad = np.full((len(picks), 2, overlay.shape[2], 3), 255, np.uint8)
            columns = np.concatenate([targets, pad, overlay], 1)  # (k, 2H + 2, W, 3)
            columns = np.concatenate([columns, np.full((len(picks), columns.shape[1], 2, 3), 255, np.uint8)], 2)
            strips.append((f"{name}: {kind}", np.concatenate(list(columns), 1)))
    fig, axes = plt.subplots(len(strips), 1, figsize=(1.2 * args.examples, 2.7 * len(strips)), squeeze=False)
    for ax, (title, strip) in zip(axes[:, 0], strips):
        ax.imshow(strip)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(args.examples_png)), exist_ok=True)
    fig.savefig(args.examples_png, dpi=100)
    plt.close(fig)


def model_sized(images: np.ndarray, side: int) -> np.ndarray:
    """uint8 images (N, h, w, 3) resized to side x side (nearest), to stand next to the scenes."""
    rows = np.arange(side) * images.shape[1] // side
    cols = np.arange(side) * images.shape[2] // side
    return images[:, rows][:, :, cols]


def rollout_tables(model, data: dict, counts: dict, name: str, largest_component: bool) -> list[str]:
    """For a rollout-frame set: what the false positives on target-absent frames lie on, and the metrics
    per source policy."""
    absent = np.flatnonzero(~data["mask"].any((1, 2)))
    pred = np.zeros(data["mask"].shape, bool)
    for i in range(0, len(absent), 64):
        rows = absent[i : i + 64]
        pred[rows] = model.predict(data["scene"][rows], data["target"][rows], largest_component).numpy()
    kinds = attribute_false_positives(pred, data)
    lines = [
        "",
        f"{name}: what the false positives lie on ({len(absent)} frames without the target; share of them):",
        "",
        "| " + " | ".join(kinds) + " | any |",
        "|" + "---|" * (len(kinds) + 1),
        "| " + " | ".join(f"{v / max(len(absent), 1):.3f} ({v})" for v in kinds.values()) + f" | "
        f"{sum(kinds.values()) / max(len(absent), 1):.3f} |",
        "",
        f"{name} by source policy:",
        "",
        "| source | frames (with target) | target IoU | IoU (≥20 px) | FP rate (absent) | box error |",
        "|---|---|---|---|---|---|",
    ]
    for index, source in enumerate(SOURCES):
        sel = torch.from_numpy(data["source"] == index)
        if not sel.any():
            continue
        part = {k: v[sel] for k, v in counts.items()}
        m = summarize_counts(part)
        lines.append(
            f"| {source} | {int(sel.sum())} ({m['samples_with_target']}) | {m['target_iou']:.3f} | "
            f"{iou_20px(part):.3f} | {m['false_positive_rate']:.3f} | {m['box_error']:.3f} |"
        )
    if "visible_fraction" in data and (data["visible_fraction"] < MIN_VISIBLE_FRACTION).any():
        lines += ["", f"{name} by occlusion (frames with the target):", ""]
        lines += ["| target | frames | target IoU | IoU (≥20 px) | miss rate |", "|---|---|---|---|---|"]
        visible, present = torch.from_numpy(data["visible_fraction"]), counts["true"] > 0
        for label, sel in (
            ("not hidden", present & (visible >= MIN_VISIBLE_FRACTION)),
            ("partly hidden by a panel", present & (visible < MIN_VISIBLE_FRACTION)),
        ):
            part = {k: v[sel] for k, v in counts.items()}
            m = summarize_counts(part)
            lines.append(
                f"| {label} | {int(sel.sum())} | {m['target_iou']:.3f} | {iou_20px(part):.3f} | {m['miss_rate']:.3f} |"
            )
    return lines


def bar_table(model, datasets: dict, args: Args) -> list[str]:
    """Markdown lines: each data set's IoU on targets of ≥ 20 px, miss rate and false-positive rate with the
    verifier's bar at each of `args.verifier_bars` (the model's config is restored after)."""
    if not args.verifier_bars:
        return []
    lines = [
        "",
        "At other verifier bars (the checkpoint's: "
        f"{model.config.verifier_threshold}; regions cut by the border keep theirs):",
        "",
        "| data set | bar | IoU (≥20 px) | miss rate | FP rate (absent) |",
        "|---|---|---|---|---|",
    ]
    config = model.config
    try:
        for data_dir, data in datasets.items():
            for bar in args.verifier_bars:
                model.config = dataclasses.replace(config, verifier_threshold=bar)
                with torch.inference_mode():
                    counts = dataset_counts(model, data, largest_component=args.largest_component)
                metrics = summarize_counts(counts)
                lines.append(
                    f"| {data_dir} | {bar} | {iou_20px(counts):.3f} | {metrics['miss_rate']:.3f} | {metrics['false_positive_rate']:.3f} |"
                )
    finally:
        model.config = config
    return lines


def main(args: Args):
    torch.set_num_threads(1)
    weights = args.weights or WEIGHTS_PATH
    bad = [b for b in args.verifier_bars if not 0 < b < 1]
    if bad:  # before the checkpoint is loaded
        raise ValueError(f"--verifier-bars {bad}: each bar must be in (0, 1)")
    model, checkpoint = load_checkpoint(weights)
    if args.verifier_bars and model.verifier is None:
        raise ValueError(f"--verifier-bars {args.verifier_bars}: {weights} has no verifier (its network alone)")
    if args.presence_threshold is not None:
        model.config = dataclasses.replace(model.config, presence_threshold=args.presence_threshold)
    if args.segment_size:
        segmenting_at(model, args.segment_size)
    lines = [
        f"FCN `{weights}` (trained at {model.config.image_size}², epoch {checkpoint.get('epoch')})"
        + (f", segmenting at {args.segment_size}²" if args.segment_size else "")
        + (", largest connected component kept" if args.largest_component else "")
        + (f", presence threshold {model.config.presence_threshold}" if model.config.presence_head else ""),
        "",
        "| data set | objects | size | samples (with target) | pixel acc | target IoU | pooled IoU | FP rate (absent) | box error | miss rate | IoU (target ≥1%) | IoU (≥20 px) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    attribution = []
    bins = list(zip(SIZE_BINS[:-1], SIZE_BINS[1:]))
    by_size = [
        "",
        "Target IoU by the target's share of the image (samples in brackets):",
        "",
        "| data set | " + " | ".join(f"{lo:.1%}–{hi:.1%}" if hi <= 1 else f"≥ {lo:.0%}" for lo, hi in bins) + " |",
        "|---|" + "---|" * len(bins),
    ]
    datasets, all_counts = {}, {}
    for data_dir in args.data_dirs:
        with open(os.path.join(data_dir, "manifest.json")) as f:
            config = json.load(f)["config"]
        data = load_segmentation_data(data_dir)
        started = time.time()
        with torch.inference_mode():
            counts = dataset_counts(model, data, largest_component=args.largest_component)
        metrics = summarize_counts(counts)
        datasets[data_dir], all_counts[data_dir] = data, counts
        large = counts["true"] >= 0.01 * counts["pixels"]
        metrics["target_iou_large"] = summarize_counts({k: v[large] for k, v in counts.items()})["target_iou"]
        metrics["target_iou_20px"] = iou_20px(counts)
        n = metrics["samples_with_target"] + metrics["samples_without_target"]
        values = " | ".join(
            f"{metrics[c]:.4f}" if c == "pixel_accuracy" else f"{metrics[c]:.3f}"
            for c in COLUMNS + ("target_iou_large", "target_iou_20px")
        )
        lines.append(
            f"| {data_dir} | {config['object_set']} | {config['image_size']}² | {n} ({metrics['samples_with_target']}) | {values} |"
        )
        share = counts["true"].float() / counts["pixels"]
        cells = []
        for lo, hi in bins:
            sel = (counts["true"] > 0) & (share >= lo) & (share < hi)
            iou = summarize_counts({k: v[sel] for k, v in counts.items()})["target_iou"]
            cells.append(f"{iou:.3f} ({int(sel.sum())})" if sel.any() else "–")
        by_size.append(f"| {data_dir} | " + " | ".join(cells) + " |")
        if "objects" in data:
            attribution += rollout_tables(model, data, counts, data_dir, args.largest_component)
        print(f"{data_dir}: {json.dumps(metrics)} ({time.time() - started:.0f} s)")
    table = "\n".join(lines + by_size + attribution + bar_table(model, datasets, args))
    print(table)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        f.write(table + "\n")
    print(f"written to {args.out}")
    if args.examples_png:
        plot_examples(model, datasets, all_counts, args)
        print(f"examples: {args.examples_png}")


if __name__ == "__main__":
    main(tyro.cli(Args))
