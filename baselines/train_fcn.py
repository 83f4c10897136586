"""Train the one-shot segmentation FCN (agents/fcn.py) on data from baselines/collect_segmentation_data.py.

Pixelwise cross-entropy, as in the paper. Class imbalance (the target is ~3% of the pixels): the target
class is weighted by the square root of its inverse pixel frequency in the training set (`class_weights`);
full inverse frequency over-predicts the target. Added to it (`--iou-loss-weight`): a soft-IoU loss in which
every sample with the target counts the same, whatever the target's size (the per-sample IoU we report is
dominated by small, far targets, which pixelwise cross-entropy barely weighs). Half the samples are mirrored
left-right (`--flip`). With `--presence-head`, a binary cross-entropy on "target in view" (frames with at least
`--presence-min-pixels` target pixels are positives, frames without any are negatives, slivers in between are
left out) is added (`--presence-loss-weight`). `--extra-train-dirs` adds data sets (e.g. rollout frames from
`baselines/collect_rollout_frames.py`) to the training set, area-downsampled to the training size when they
are larger. `scripts/make_fcn.sh` gives the recipe of the shipped weights.

Validation (train objects, other scenes) every epoch; the best epoch by validation target IoU minus the false-
positive rate on target-absent samples (`--select-by`) is saved
with its config to RUN_DIR/best.pt, every epoch to RUN_DIR/last.pt (with the optimiser: `--resume`
continues from it); curves to RUN_DIR/curves.png.

  python baselines/train_fcn.py --data-dir data/seg64 --run-dir runs/fcn
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import asdict, dataclass, field

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch
import torch.nn.functional as F
import tyro
from tqdm import tqdm

from mani_active_vision.agents.fcn import (
    FCNConfig,
    OneShotFCN,
    choose_presence_threshold,
    class_weights,
    dataset_counts,
    flip_horizontally,
    images_to_input,
    load_checkpoint,
    save_checkpoint,
    soft_iou_loss,
    summarize_counts,
)
from mani_active_vision.json_io import save_json
from mani_active_vision.segmentation_data import load_segmentation_data, load_segmentation_sets


@dataclass
class Args:
    data_dir: str = "data/seg64"
    """folder with train/ and val/ data sets"""
    run_dir: str = "runs/fcn"
    """where checkpoints, history.json and curves.png go"""
    epochs: int = 12
    """passes over the training set"""
    batch_size: int = 32
    """samples per step"""
    lr: float = 2e-3
    """Adam learning rate at the start; cosine decay to lr/20 over `epochs`"""
    weight_power: float = 0.5
    """target class weight = (inverse pixel frequency) ** weight_power; 0 = plain cross-entropy"""
    iou_loss_weight: float = 1.0
    """weight of a soft-IoU loss (`soft_iou_loss`: every sample with the target counts the same) added to the cross-entropy"""
    flip: bool = True
    """augment: mirror half the samples left-right (scene, mask and target image together)"""
    channels: tuple[int, int, int] = (16, 32, 64)
    """encoder channels at 1/2, 1/4, 1/8 of the image side"""
    full_res_channels: int = 8
    """features of the full-resolution skip (`FCNConfig.full_res_channels`; 0: none)"""
    target_pooling: str = "max"
    """`FCNConfig.target_pooling`: max (the paper's) | masked (prototypes over the target's pixels + similarity)"""
    shape_kernel: int = 0
    """`FCNConfig.shape_kernel`: 0 none; k: the target's k×k kernel cross-correlated at 1/4 and 1/8"""
    presence_head: bool = False
    """`FCNConfig.presence_head`: an image-level "target in view" score that gates the mask"""
    presence_loss_weight: float = 1.0
    """weight of the presence head's binary cross-entropy"""
    presence_min_pixels: int = 8
    """a training frame with at least this many target pixels is "in view" for the presence head (fewer but
    some: left out of that loss)"""
    extra_train_dirs: list[str] = field(default_factory=list)
    """more data sets added to DATA_DIR/train (e.g. rollout frames), downsampled to the training size"""
    select_by: str = "iou_minus_fp"
    """the saved best epoch: highest validation iou_minus_fp (target IoU - FP rate) | target_iou"""
    seed: int = 0
    """torch and shuffling seed"""
    threads: int = 1
    """torch threads (the machine is shared)"""
    resume: bool = False
    """continue from RUN_DIR/last.pt"""


def selection_score(metrics: dict, select_by: str) -> float:
    """The validation score the best epoch is chosen by (see `Args.select_by`)."""
    if select_by == "target_iou":
        return metrics["target_iou"]
    return metrics["target_iou"] - metrics["false_positive_rate"]


def plot_curves(history: list[dict], path: str, loss_name: str = "weighted cross-entropy") -> None:
    epochs = [h["epoch"] for h in history]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot(epochs, [h["train_loss"] for h in history], label="train")
    axes[0].plot(epochs, [h["val_loss"] for h in history], label="val")
    axes[0].set_title(loss_name)
    axes[1].plot(epochs, [h["val"]["target_iou"] for h in history], label="target IoU (per sample)")
    axes[1].plot(epochs, [h["val"]["pooled_target_iou"] for h in history], label="target IoU (pooled)")
    axes[1].plot(epochs, [h["val"]["pixel_accuracy"] for h in history], label="pixel accuracy")
    axes[1].set_title("validation")
    axes[2].plot(epochs, [h["val"]["false_positive_rate"] for h in history], label="FP rate (absent samples)")
    axes[2].set_title("validation, samples without target")
    for ax in axes:
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(args: Args):
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # tiny soft-IoU gradients turn denormal and slowed training steps ~1.5x
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    os.makedirs(args.run_dir, exist_ok=True)
    if args.select_by not in ("iou_minus_fp", "target_iou"):
        raise ValueError(f"select_by={args.select_by!r} is not one of: iou_minus_fp, target_iou")
    train = load_segmentation_sets([os.path.join(args.data_dir, "train"), *args.extra_train_dirs])
    val = load_segmentation_data(os.path.join(args.data_dir, "val"))
    image_size = train["scene"].shape[1]
    target_share = float(train["mask"].mean())
    weights = class_weights(target_share, args.weight_power)
    print(
        f"train {len(train['mask'])} samples, val {len(val['mask'])}; {image_size}² scenes; target pixels {target_share:.4f} "
        f"-> class weights {weights.tolist()}"
    )

    model = OneShotFCN(
        FCNConfig(
            channels=args.channels,
            image_size=image_size,
            target_size=train["target"].shape[1],
            full_res_channels=args.full_res_channels,
            target_pooling=args.target_pooling,
            shape_kernel=args.shape_kernel,
            presence_head=args.presence_head,
        )
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    history, start_epoch, best_iou = [], 0, -1.0
    last_path, best_path = os.path.join(args.run_dir, "last.pt"), os.path.join(args.run_dir, "best.pt")
    if args.resume:
        model, checkpoint = load_checkpoint(last_path)
        optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
        optimizer.load_state_dict(checkpoint["optimizer"])
        history = checkpoint["history"]
        start_epoch = len(history)
        best_iou = max(selection_score(h["val"], args.select_by) for h in history)
        print(f"resumed from {last_path} after epoch {start_epoch}")
    print(f"parameters: {sum(p.numel() for p in model.parameters())}")

    def loss_fn(scene: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        scores, presence = model.segment_with_presence(scene, model.target_features(target))
        loss = F.cross_entropy(scores, mask.long(), weight=weights)
        if args.iou_loss_weight:
            loss = loss + args.iou_loss_weight * soft_iou_loss(scores, mask)
        if presence is not None:
            pixels = mask.flatten(1).sum(1)
            labelled = (pixels == 0) | (pixels >= args.presence_min_pixels)
            if labelled.any():
                in_view = (pixels[labelled] > 0).float()
                presence_loss = F.binary_cross_entropy_with_logits(presence[labelled], in_view)
                loss = loss + args.presence_loss_weight * presence_loss
        return loss

    num_train = len(train["mask"])
    steps_per_epoch = math.ceil(num_train / args.batch_size)
    for epoch in range(start_epoch, args.epochs):
        lr = args.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * epoch / args.epochs)))
        for group in optimizer.param_groups:
            group["lr"] = lr
        model.train()
        order = rng.permutation(num_train)
        losses, started = [], time.time()
        for step in tqdm(range(steps_per_epoch), desc=f"epoch {epoch + 1}/{args.epochs}", leave=False):
            idx = np.sort(order[step * args.batch_size : (step + 1) * args.batch_size])
            scene, target, mask = (
                images_to_input(train["scene"][idx]),
                images_to_input(train["target"][idx]),
                torch.from_numpy(train["mask"][idx]),
            )
            if args.flip:
                scene, target, mask = flip_horizontally(
                    scene, target, mask, where=torch.from_numpy(rng.random(len(idx)) < 0.5)
                )
            loss = loss_fn(scene, target, mask)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
        train_seconds = time.time() - started

        model.eval()
        with torch.inference_mode():
            val_losses = [
                loss_fn(
                    images_to_input(val["scene"][i : i + 128]),
                    images_to_input(val["target"][i : i + 128]),
                    torch.from_numpy(val["mask"][i : i + 128]),
                ).item()
                for i in range(0, len(val["mask"]), 128)
            ]
        metrics = summarize_counts(dataset_counts(model, val))
        history.append(
            dict(
                epoch=epoch + 1,
                lr=lr,
                train_loss=float(np.mean(losses)),
                val_loss=float(np.mean(val_losses)),
                val=metrics,
                train_seconds=round(train_seconds, 1),
            )
        )
        print(
            f"epoch {epoch + 1:2d} lr {lr:.2e} train loss {np.mean(losses):.4f} val loss {np.mean(val_losses):.4f} "
            f"val IoU {metrics['target_iou']:.3f} (pooled {metrics['pooled_target_iou']:.3f}) "
            f"pixel acc {metrics['pixel_accuracy']:.4f} FP rate {metrics['false_positive_rate']:.3f} ({train_seconds:.0f} s)"
        )
        save_checkpoint(last_path, model, optimizer=optimizer.state_dict(), history=history, args=asdict(args))
        if selection_score(metrics, args.select_by) > best_iou:
            best_iou = selection_score(metrics, args.select_by)
            save_checkpoint(
                best_path, model, epoch=epoch + 1, val=metrics, args=asdict(args), class_weights=weights.tolist()
            )
        save_json(history, os.path.join(args.run_dir, "history.json"))
        loss_name = (
            "weighted cross-entropy"
            + (f" + {args.iou_loss_weight:g} × soft IoU" if args.iou_loss_weight else "")
            + (f" + {args.presence_loss_weight:g} × presence BCE" if args.presence_head else "")
        )
        plot_curves(history, os.path.join(args.run_dir, "curves.png"), loss_name)
    model, checkpoint = load_checkpoint(best_path)
    if model.config.presence_head:  # the gate's threshold, chosen on validation like the epoch
        threshold, rows = choose_presence_threshold(model, val)
        model.config = dataclasses.replace(model.config, presence_threshold=threshold)
        extra = {k: v for k, v in checkpoint.items() if k not in ("format", "config", "state_dict")}
        save_checkpoint(best_path, model, **extra, presence_thresholds=rows)
        print(
            "presence threshold on validation: "
            + ", ".join(
                f"{r['threshold']:.2f}: IoU {r['target_iou']:.3f} FP {r['false_positive_rate']:.3f}" for r in rows
            )
            + f" -> {threshold:.2f}"
        )
    print(f"best val {args.select_by} {best_iou:.3f}: {best_path}; curves: {os.path.join(args.run_dir, 'curves.png')}")


if __name__ == "__main__":
    main(tyro.cli(Args))
