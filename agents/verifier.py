"""Verify the FCN's candidate regions: is the object under this region the target of the picture?

The segmentation network proposes; on the frames a policy sees it marks a same-colour look-alike almost
whenever one is in view (docs/vision.md). The target image shows the side of the target the robot sees
(design.md §8), so the target's outline in the wrist view matches its picture and a look-alike's does not
(silhouette ROC AUC 0.99 from 20 px at 128²). This small Siamese network looks at a square crop of the scene
around each candidate region, at the camera's full resolution, beside the same crop of the target image (its
box of non-grey pixels), both scaled to `crop`² so that size does not matter, and scores "same object".
Two-stage, as detectors verify their proposals; `OneShotFCN` keeps the regions it accepts.
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage
import torch
import torch.nn as nn
import torch.nn.functional as F

MARGIN = 1.6
"""a crop's side over its region's longer side: the whole object and a little floor, when the region covers
only part of it"""
MIN_SIDE = 12.0
"""smallest crop side in scene pixels: a speck's crop shows what is around it"""
TRACK_GROW = 0.5
"""how far (× its size, on every side) a region may lie from the previous step's kept region and still be
the same object (`near_previous`): one 5 cm step moves a box by less than its size"""


def _conv(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1), nn.ReLU(inplace=True))


class CandidateVerifier(nn.Module):
    """(target crops, candidate crops), float (M, 3, crop, crop) each -> "same object" logits (M,).

    One encoder for both (to 1/8 of the crop), then a comparison that keeps the layout: at every cell both
    features, their product and their absolute difference, a 1×1 convolution, and two linear layers over
    all cells."""

    def __init__(self, crop: int = 32, channels: tuple[int, int, int] = (16, 32, 64)):
        super().__init__()
        if crop % 8:
            raise ValueError(f"crop={crop} must be a multiple of 8")
        c1, c2, c3 = channels
        self.crop = crop
        self.encoder = nn.Sequential(_conv(3, c1), _conv(c1, c2, 2), _conv(c2, c3, 2), _conv(c3, c3, 2))
        self.compare = nn.Sequential(nn.Conv2d(4 * c3, c3, 1), nn.ReLU(inplace=True))
        cells = (crop // 8) ** 2
        self.head = nn.Sequential(
            nn.Flatten(), nn.Dropout(0.3), nn.Linear(c3 * cells, 64), nn.ReLU(inplace=True), nn.Linear(64, 1)
        )

    def forward(self, target_crops: torch.Tensor, candidate_crops: torch.Tensor) -> torch.Tensor:
        return self.score(self.encoder(target_crops), self.encoder(candidate_crops))

    def score(self, target_encoded: torch.Tensor, candidate_encoded: torch.Tensor) -> torch.Tensor:
        """Logits (M,) of encoded crops (M, C, crop/8, crop/8): an episode encodes its target's crop once."""
        t, c = target_encoded, candidate_encoded
        return self.head(self.compare(torch.cat([t, c, t * c, (t - c).abs()], 1)))[:, 0]


def square_crops(
    images: torch.Tensor, boxes: torch.Tensor, size: int, margin: float = MARGIN, image: torch.Tensor | None = None
) -> torch.Tensor:
    """Crops (M, C, size, size) of float images (M, C, H, W) around pixel boxes (M, 4) = (x0, y0, x1, y1),
    edges exclusive: a square of side `margin` × the longer side (at least MIN_SIDE), centred on the box,
    bilinear; outside the image is 0 (grey 128 after `normalize_images`, the target image's background).
    With `image` (M,), box k is in images[image[k]] (images (N, C, H, W)): one image's crops are then sampled
    in one pass, without a copy of the image per box (an episode's frame: the same crops bit for bit)."""
    height, width = images.shape[2:]
    centre = (boxes[:, :2] + boxes[:, 2:]) / 2
    side = ((boxes[:, 2:] - boxes[:, :2]).amax(1) * margin).clamp_min(MIN_SIDE)
    t = (torch.arange(size, dtype=images.dtype, device=images.device) + 0.5) / size - 0.5  # (size,) in [-.5, .5]
    xs = (centre[:, :1] + side[:, None] * t) / width * 2 - 1  # (M, size) in grid_sample's [-1, 1]
    ys = (centre[:, 1:] + side[:, None] * t) / height * 2 - 1
    grid = torch.stack([xs[:, None, :].expand(-1, size, -1), ys[:, :, None].expand(-1, -1, size)], -1)
    if image is not None and len(images) == 1:  # every box's grid stacked into one tall grid over the one image
        crops = F.grid_sample(images, grid.reshape(1, -1, size, 2), align_corners=False, padding_mode="zeros")
        return crops.view(images.shape[1], len(boxes), size, size).transpose(0, 1).contiguous()
    if image is not None:
        images = images[image]
    return F.grid_sample(images, grid, align_corners=False, padding_mode="zeros")


def mask_box(mask: torch.Tensor) -> torch.Tensor:
    """Pixel boxes (N, 4) = (x0, y0, x1, y1), edges exclusive, of bool masks (N, H, W); the whole image where
    a mask is empty."""
    n, height, width = mask.shape
    rows, cols = mask.any(2), mask.any(1)
    boxes = []
    for hits, n_px in ((cols, width), (rows, height)):
        steps = torch.arange(n_px, device=mask.device)
        low = torch.where(hits, steps, n_px).amin(1)
        high = torch.where(hits, steps, -1).amax(1) + 1
        empty = ~hits.any(1)
        boxes.append((torch.where(empty, 0, low), torch.where(empty, n_px, high)))
    (x0, x1), (y0, y1) = boxes
    return torch.stack([x0, y0, x1, y1], 1).float()


def regions(mask: np.ndarray, max_regions: int) -> tuple[np.ndarray, list[int], list[int]]:
    """(8-connected labels (H, W), the labels of the `max_regions` largest regions, largest first, their pixel
    counts)."""
    labels, count = scipy.ndimage.label(mask, structure=np.ones((3, 3)))
    if not count:
        return labels, [], []
    sizes = np.bincount(labels.ravel())[1:]
    largest = np.argsort(-sizes, kind="stable")[:max_regions]
    return labels, (largest + 1).tolist(), sizes[largest].tolist()


def region_boxes(labels: np.ndarray, ids: list[int]) -> torch.Tensor:
    """Pixel boxes (len(ids), 4) of the regions `ids` of a label image."""
    slices = scipy.ndimage.find_objects(labels)
    return torch.tensor(
        [[slices[k - 1][1].start, slices[k - 1][0].start, slices[k - 1][1].stop, slices[k - 1][0].stop] for k in ids],
        dtype=torch.float32,
    ).reshape(-1, 4)


def target_crops(target: torch.Tensor, target_pixels: torch.Tensor, crop: int) -> torch.Tensor:
    """Crops (N, 3, crop, crop) of normalised target images (N, 3, h, w) around their non-grey pixels
    (N, h, w), framed as `square_crops` frames a candidate."""
    return square_crops(target, mask_box(target_pixels), crop)


def candidate_crops(scene: torch.Tensor, masks: np.ndarray, max_regions: int, crop: int) -> dict:
    """The verifier's inputs for every image's `max_regions` largest candidate regions.

    scene (N, 3, H, W) normalised images, masks (N, H, W) bool candidate masks. Returns dict(scene_crops
    (M, 3, crop, crop), image (M,) the image each region is in, labels [(H, W) int per image], ids [region
    labels per image, largest first], boxes (M, 4) the regions' pixel boxes, sizes (M,) their pixel counts)."""
    labels, ids, boxes, image, sizes = [], [], [], [], []
    for i, mask in enumerate(masks):
        image_labels, image_ids, image_sizes = regions(mask, max_regions)
        labels.append(image_labels)
        ids.append(image_ids)
        boxes.append(region_boxes(image_labels, image_ids))
        image += [i] * len(image_ids)
        sizes += image_sizes
    image = torch.tensor(image, dtype=torch.long)
    boxes = torch.cat(boxes).to(scene.device)
    if len(image):
        scene_crops = square_crops(scene, boxes, crop, image=image.to(scene.device))
    else:  # no region anywhere (~40% of an episode's frames): no sampling to set up
        scene_crops = scene.new_zeros((0, scene.shape[1], crop, crop))
    sizes = torch.tensor(sizes, dtype=torch.long)
    return dict(scene_crops=scene_crops, image=image, labels=labels, ids=ids, boxes=boxes, sizes=sizes)


def at_border(boxes: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """(M,) bool: whether each pixel box (M, 4) (x0, y0, x1, y1; the stops exclusive) touches the border of an
    image of `shape` (H, W): a region cut by the border, or lying along it."""
    height, width = shape
    return (boxes[:, 0] <= 0) | (boxes[:, 1] <= 0) | (boxes[:, 2] >= width) | (boxes[:, 3] >= height)


def cut_regions(candidates: dict, shape: tuple[int, int], share: float) -> torch.Tensor:
    """(M,) bool: which of `candidate_crops`' regions touch the border of their (H, W) image and cover at least
    `share` of it: the large regions cut by the border (`FCNConfig.verifier_cut_share`)."""
    return at_border(candidates["boxes"], shape) & (
        candidates["sizes"].to(candidates["boxes"].device) >= share * shape[0] * shape[1]
    )


def near_previous(boxes: torch.Tensor, image: torch.Tensor, previous: torch.Tensor, grow: float = TRACK_GROW):
    """(M,) bool: whether each candidate's pixel box (M, 4) meets the box of the region kept in its image at
    the previous step, grown by `grow` × its size on every side; `previous` (N, H, W) bool masks, empty
    where nothing was kept."""
    kept = mask_box(previous)[image]
    size = kept[:, 2:] - kept[:, :2]
    low, high = kept[:, :2] - grow * size, kept[:, 2:] + grow * size
    meets = (boxes[:, :2] < high).all(1) & (boxes[:, 2:] > low).all(1)
    return meets & previous.flatten(1).any(1)[image]


def keep_verified(candidates: dict, probability: torch.Tensor, threshold, num_images: int, best_only: bool = False):
    """(masks (N, H, W) bool of the regions whose probability is at least `threshold` (a float, or one per
    region (M,)) (with `best_only`, only the most probable of them), presence (N,) = the best region's
    probability, 0 for an image without regions)."""
    masks = np.zeros((num_images, *candidates["labels"][0].shape), dtype=bool) if num_images else np.zeros((0, 0, 0))
    presence = torch.zeros(num_images)
    probability = probability.cpu()
    threshold = torch.as_tensor(threshold, dtype=probability.dtype).cpu().expand_as(probability)
    start = 0
    for i, (labels, ids) in enumerate(zip(candidates["labels"], candidates["ids"])):
        p = probability[start : start + len(ids)]
        bar = threshold[start : start + len(ids)]
        start += len(ids)
        if len(ids):
            presence[i] = p.max()
            accepted = [(q, k) for k, q, b in zip(ids, p.tolist(), bar.tolist()) if q >= b]
            accepted = [max(accepted, key=lambda a: a[0])[1]] if best_only and accepted else [k for _, k in accepted]
            masks[i] = np.isin(labels, accepted)
    return torch.from_numpy(masks), presence
