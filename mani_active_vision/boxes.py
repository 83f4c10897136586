"""Masks to boxes and the target statistics that reward and success are made of (batched, torch).

Every env step computes them on one small mask; on the CPU that is done in numpy, where torch's overhead per
operation was most of their time (docs/speed.md), with the same results bit for bit (tested); other devices
keep the batched torch code."""

from __future__ import annotations

import numpy as np
import scipy.ndimage
import torch
import torch.nn.functional as F


def mask_to_box(mask: torch.Tensor) -> torch.Tensor:
    """Bounding boxes (N, 4) = (x, y, w, h) of boolean masks (N, H, W), normalised by the image size.

    (x, y) is the top-left corner; a box covers whole pixels, so one pixel has w = 1/W. Zeros where a
    mask is empty. The one place the project turns a mask into the 4-number state.
    """
    if mask.ndim != 3 or mask.dtype != torch.bool:
        raise ValueError(f"mask must be a bool tensor (N, H, W), got {tuple(mask.shape)} {mask.dtype}")
    if mask.device.type == "cpu":
        return torch.from_numpy(_box_numpy(mask.numpy()))
    return _box_torch(mask)


def _box_torch(mask: torch.Tensor) -> torch.Tensor:
    """`mask_to_box` in batched torch (any device)."""
    n, h, w = mask.shape
    rows, cols = mask.any(2), mask.any(1)
    row_idx = torch.arange(h, device=mask.device)
    col_idx = torch.arange(w, device=mask.device)
    top = torch.where(rows, row_idx, h).amin(1)
    bottom = torch.where(rows, row_idx, -1).amax(1)
    left = torch.where(cols, col_idx, w).amin(1)
    right = torch.where(cols, col_idx, -1).amax(1)
    box = torch.stack([left / w, top / h, (right - left + 1) / w, (bottom - top + 1) / h], -1).float()
    return torch.where(rows.any(1)[:, None], box, torch.zeros_like(box))


def _box_numpy(mask: np.ndarray, rows: np.ndarray | None = None, cols: np.ndarray | None = None) -> np.ndarray:
    """`mask_to_box` of a numpy bool mask (N, H, W), from its rows and columns with a pixel if given."""
    n, h, w = mask.shape
    rows = mask.any(2) if rows is None else rows
    cols = mask.any(1) if cols is None else cols
    top, left = rows.argmax(1), cols.argmax(1)
    bottom, right = h - 1 - rows[:, ::-1].argmax(1), w - 1 - cols[:, ::-1].argmax(1)
    box = np.stack([left / w, top / h, (right - left + 1) / w, (bottom - top + 1) / h], -1).astype(np.float32)
    return box * rows.any(1)[:, None]


def largest_component(mask: torch.Tensor, min_pixels: int = 1) -> torch.Tensor:
    """Keep, per image of a bool mask (N, H, W), only its largest 8-connected component, and only if it has
    at least `min_pixels` pixels (else the mask is emptied). Drops the stray specks a segmentation
    network marks on look-alike objects, which would otherwise stretch or move the box."""
    if mask.ndim != 3 or mask.dtype != torch.bool:
        raise ValueError(f"mask must be a bool tensor (N, H, W), got {tuple(mask.shape)} {mask.dtype}")
    kept = np.zeros(mask.shape, dtype=bool)
    for i, image in enumerate(mask.cpu().numpy()):
        labels, count = scipy.ndimage.label(image, structure=np.ones((3, 3)))
        if count:
            sizes = np.bincount(labels.ravel())[1:]
            if sizes.max() >= min_pixels:
                kept[i] = labels == 1 + sizes.argmax()
    return torch.from_numpy(kept).to(mask.device)


def centroid(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each mask's pixel count and its centroid (x, y) in pixels (pixel centres at +0.5; 0 for an empty mask)."""
    if mask.device.type == "cpu":
        return tuple(torch.from_numpy(x) for x in _centroid_numpy(mask.numpy()))
    return _centroid_torch(mask)


def _centroid_torch(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`centroid` in batched torch (any device)."""
    n, h, w = mask.shape
    area = mask.sum((1, 2))
    ys = torch.arange(h, device=mask.device, dtype=torch.float32) + 0.5
    xs = torch.arange(w, device=mask.device, dtype=torch.float32) + 0.5
    safe_area = area.clamp(min=1).float()
    return area, (mask.sum(1).float() * xs).sum(1) / safe_area, (mask.sum(2).float() * ys).sum(1) / safe_area


def _centroid_numpy(mask: np.ndarray, rows: np.ndarray | None = None, cols: np.ndarray | None = None) -> tuple:
    """`centroid` of a numpy bool mask (N, H, W), from its pixel counts per row (N, H) and column (N, W) if given.
    (The sums are of whole and half numbers below 2^24: exact in float32 in any order, so equal to torch's.)"""
    n, h, w = mask.shape
    rows = mask.sum(2) if rows is None else rows
    cols = mask.sum(1) if cols is None else cols
    area = rows.sum(1)
    safe_area = np.maximum(area, 1).astype(np.float32)
    xs = np.arange(w, dtype=np.float32) + np.float32(0.5)
    ys = np.arange(h, dtype=np.float32) + np.float32(0.5)
    return area, (cols.astype(np.float32) * xs).sum(1) / safe_area, (rows.astype(np.float32) * ys).sum(1) / safe_area


def mask_stats(mask: torch.Tensor) -> torch.Tensor:
    """(N, 3): each mask's share of the image and its centroid's offset from the image centre (dx, dy, as
    fractions of the width, as `target_stats`' center_offset is); zeros for an empty mask."""
    n, h, w = mask.shape
    if mask.device.type == "cpu":
        area, cx, cy = _centroid_numpy(mask.numpy())
        offset = np.stack([(cx - w / 2) / w, (cy - h / 2) / w], -1) * (area > 0)[:, None]
        return torch.from_numpy(np.concatenate([(area.astype(np.float32) / (h * w))[:, None], offset], -1))
    return _mask_stats_torch(mask)


def _mask_stats_torch(mask: torch.Tensor) -> torch.Tensor:
    """`mask_stats` in batched torch (any device)."""
    n, h, w = mask.shape
    area, cx, cy = _centroid_torch(mask)
    offset = torch.stack([(cx - w / 2) / w, (cy - h / 2) / w], -1) * (area > 0)[:, None]
    return torch.cat([(area.float() / (h * w))[:, None], offset], -1)


def target_stats(mask: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-image facts about a boolean target mask (N, H, W).

    target_fraction: share of pixels that are target; target_visible; target_bbox (see mask_to_box);
    touches_border: a target pixel lies on the image border; center_offset: distance of the mask's
    centroid from the image centre, as a fraction of the image width (inf when not visible).
    """
    if mask.device.type == "cpu":
        return _target_stats_numpy(mask.numpy())
    return _target_stats_torch(mask)


def _target_stats_torch(mask: torch.Tensor) -> dict[str, torch.Tensor]:
    """`target_stats` in batched torch (any device)."""
    n, h, w = mask.shape
    area, cx, cy = _centroid_torch(mask)
    visible = area > 0
    border = mask[:, 0, :].any(1) | mask[:, -1, :].any(1) | mask[:, :, 0].any(1) | mask[:, :, -1].any(1)
    offset = torch.sqrt((cx - w / 2) ** 2 + (cy - h / 2) ** 2) / w
    return dict(
        target_fraction=area.float() / (h * w),
        target_visible=visible,
        target_bbox=_box_torch(mask),
        touches_border=border,
        center_offset=torch.where(visible, offset, torch.full_like(offset, float("inf"))),
    )


def _target_stats_numpy(mask: np.ndarray) -> dict[str, torch.Tensor]:
    """`target_stats` of a numpy bool mask (N, H, W): one count per row and column, everything from them."""
    n, h, w = mask.shape
    rows, cols = mask.sum(2), mask.sum(1)
    area, cx, cy = _centroid_numpy(mask, rows, cols)
    visible = area > 0
    border = (rows[:, 0] > 0) | (rows[:, -1] > 0) | (cols[:, 0] > 0) | (cols[:, -1] > 0)
    offset = torch.sqrt(torch.from_numpy((cx - w / 2) ** 2 + (cy - h / 2) ** 2)) / w  # torch's sqrt, as on a device
    return dict(
        target_fraction=torch.from_numpy(area.astype(np.float32) / (h * w)),
        target_visible=torch.from_numpy(visible),
        target_bbox=torch.from_numpy(_box_numpy(mask, rows > 0, cols > 0)),
        touches_border=torch.from_numpy(border),
        center_offset=torch.where(torch.from_numpy(visible), offset, torch.tensor(float("inf"))),
    )


def silhouette(mask: np.ndarray, side: int = 32) -> np.ndarray:
    """A mask's shape alone: cropped to its box, padded to a centred square, area-resized to side² (bool).
    Compares an object's outline in the wrist view with the target image's whatever their sizes."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        raise ValueError("silhouette of an empty mask")
    crop = mask[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1].astype(np.float32)
    h, w = crop.shape
    n = max(h, w)
    square = np.zeros((n, n), np.float32)
    square[(n - h) // 2 : (n - h) // 2 + h, (n - w) // 2 : (n - w) // 2 + w] = crop
    return F.interpolate(torch.from_numpy(square)[None, None], size=(side, side), mode="area")[0, 0].numpy() > 0.5


def silhouette_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two silhouettes (bool arrays of one shape)."""
    return float((a & b).sum() / max((a | b).sum(), 1))


def roc_auc(positive: np.ndarray, negative: np.ndarray) -> float:
    """How well one score tells two sets apart: P(a positive scores above a negative), ties counted half; NaN
    when either set is empty."""
    positive, negative = np.asarray(positive), np.asarray(negative)
    if len(positive) == 0 or len(negative) == 0:
        return float("nan")
    diff = positive[:, None] - negative[None, :]
    return float((diff > 0).mean() + 0.5 * (diff == 0).mean())
