"""One-shot segmentation FCN: given the wrist view and one picture of the target, which pixels are the target.

The paper's design (docs/design.md §10), made small enough for a CPU core and trained from scratch (no pretrained
VGG offline): one encoder, shared by both images, gives features at three depths (1/2, 1/4, 1/8 of the
image side). At each depth the target's features are global-max-pooled to 1×1, tiled over the scene's
features and concatenated with them; 1×1 convolutions fuse the pair. Transposed convolutions upsample the
deepest fused map, adding the shallower fused maps as skip connections, to two class scores per pixel
(background, target); optionally (`FCNConfig.full_res_channels`, the shipped weights use 8) a convolution
of the scene at full resolution is added before a last 3×3 convolution, for sharper edges.

That design matches colour more than shape: on frames from rollouts it marks a same-colour distractor on
most frames without the target (docs/vision.md). The discriminating configuration (docs/design.md §10)
keeps the layout and changes what the scene is matched against: `target_pooling="masked"` pools the
target's features over its own pixels (mean and max, the target image's background is a known grey) and
adds each scene feature's cosine similarity to that mean; `shape_kernel` cross-correlates a kernel of the
target's features over its bounding box with the scene's deeper features; `presence_head` scores "target in
view" for the whole image and `predict` empties the mask where that score is low.

    model = load_pretrained()                          # agents/weights/fcn.pt, ready in eval mode
    mask = model.predict(scene_rgb, target_rgb)        # uint8 (N, H, W, 3) each -> bool (N, H, W)
    mask, presence = model.predict_with_presence(scene_rgb, target_rgb)   # and (N,) "in view" probability

`predict` takes a scene of any size whose sides are multiples of 8: a size other than the one the model
was trained at (`config.image_size`) is resized to it and the scores are resized back (bilinear), so the
mask always has the scene's size. The target image is resized to `config.target_size` likewise. The
target's features are computed once per target image and reused while it and the weights stay the same.
On the CPU, `predict` runs the scene's part, and the verifier's, through ONNX Runtime (`fcn_runtime`: graphs
exported from this module's current weights, 2-4x faster one frame at a time); `runtime="torch"` runs the
model eagerly.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from mani_active_vision.agents import fcn_runtime
from mani_active_vision.agents.verifier import (
    CandidateVerifier,
    candidate_crops,
    cut_regions,
    keep_verified,
    near_previous,
    target_crops,
)
from mani_active_vision.box_state import check_thresholds
from mani_active_vision.boxes import largest_component as keep_largest_component
from mani_active_vision.boxes import mask_to_box

WEIGHTS_PATH = os.path.join(os.path.dirname(__file__), "weights", "fcn.pt")
CHECKPOINT_FORMAT = "mani_active_vision.fcn/1"
RUNTIMES = ("auto", "onnxruntime", "torch")


TARGET_POOLINGS = ("max", "masked")
TARGET_BACKGROUND = 128 / 255 - 0.5
"""The target image's background after `normalize_images`: the task paints every non-target pixel grey 128."""


@dataclass(frozen=True)
class FCNConfig:
    channels: tuple[int, int, int] = (16, 32, 64)
    """encoder channels at 1/2, 1/4 and 1/8 of the image side"""
    image_size: int = 64
    """scene side the model is trained at; `predict` resizes other sizes to it (or to `segment_size`)"""
    segment_size: int = 0
    """scene side `predict` segments at (0: `image_size`). The network is fully convolutional: at the camera's
    128² a target a few dozen pixels large keeps them, where 64² leaves it a few (a deployment choice, set by
    `load_pretrained(segment_size=...)`: on rollout frames IoU 0.70 -> 0.76 on targets of >= 20 px, for ~2 ms
    more per frame; docs/vision.md#segmenting-at-the-cameras-resolution)"""
    target_size: int = 64
    """target image side (the task's `target_image_size`)"""
    full_res_channels: int = 0
    """0: the last transposed convolution gives the class scores; > 0: it gives this many features, a 3×3
    convolution of the scene at full resolution is added to them (sharper edges on small targets) and a
    3×3 convolution gives the scores"""
    target_pooling: str = "max"
    """how the target's features become one vector per depth: "max" (the paper's): global max over the whole
    target image; "masked": mean and max over the target's own pixels only (the image's non-grey pixels, as
    the prototypes of SG-One and PANet), and the cosine similarity of every scene feature to the mean (one
    more channel into each fusion)"""
    shape_kernel: int = 0
    """0: none; k > 0: the target's features over its bounding box, resampled to k×k, are a per-target kernel
    cross-correlated channel by channel with the scene's features at 1/4 and 1/8 (as in Siamese trackers):
    the response is high where the scene's features have the target's spatial layout, which a pooled vector
    cannot express. The box normalises scale: the kernel covers the target whatever its size in the image."""
    presence_head: bool = False
    """an image-level "target in view" score from the deepest fused features, trained on target-absent frames;
    `predict` empties the mask where it is below `presence_threshold`"""
    presence_threshold: float = 0.5
    """presence probability under which `predict` reports the target absent (with `presence_head`)"""
    verifier_crop: int = 0
    """0: none; > 0: a second stage (`agents.verifier`) scores each candidate region of the mask on crops of
    this side (scene at its full resolution, beside the target image) and `predict` keeps the regions it
    accepts; the presence is then the best region's score. Trained after the segmentation network
    (`baselines/train_verifier.py`)"""
    verifier_threshold: float = 0.5
    """verifier probability a region needs to be kept"""
    verifier_regions: int = 4
    """the largest this many regions of a mask are verified; the rest are dropped"""
    verifier_cut_share: float = 0.0
    """0: off; > 0: a region that touches the image's border and covers at least this share of the image needs
    only `verifier_cut_threshold` (when that is lower than its bar). Cut by the border, the target loses the
    outline the verifier tells it by, and is turned away at every size, while on rollout frames hardly any other
    region that large and cut reaches 0.1 (docs/vision.md). Whole regions keep the bar: a look-alike seen whole
    up close is what approaching it reveals"""
    verifier_cut_threshold: float = 0.3
    """verifier probability a region cut by the border of `verifier_cut_share` or more needs"""
    verifier_mirror: bool = False
    """score each region also with both crops mirrored left-right and average the two logits (test-time
    augmentation: training mirrors pairs together, so both views are in its distribution; one noisy score
    of a small or cut region counts half)"""

    def __post_init__(self):
        if self.target_pooling not in TARGET_POOLINGS:
            raise ValueError(f"target_pooling={self.target_pooling!r} is not one of: {', '.join(TARGET_POOLINGS)}")
        if self.verifier_crop < 0 or self.verifier_crop % 8 or not 0 < self.verifier_threshold < 1:
            raise ValueError(
                f"verifier_crop={self.verifier_crop} must be 0 or a positive multiple of 8 and "
                f"verifier_threshold={self.verifier_threshold} in (0, 1)"
            )
        if not 0 <= self.verifier_cut_share < 1 or not 0 < self.verifier_cut_threshold < 1:
            raise ValueError(
                f"verifier_cut_share={self.verifier_cut_share} must be in [0, 1) and "
                f"verifier_cut_threshold={self.verifier_cut_threshold} in (0, 1)"
            )
        if self.shape_kernel < 0 or not 0 < self.presence_threshold < 1:
            raise ValueError(
                f"shape_kernel={self.shape_kernel} must be >= 0 and presence_threshold={self.presence_threshold} "
                "in (0, 1)"
            )


def _conv(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1), nn.ReLU(inplace=True))


def _fuse(channels: int, inputs: int) -> nn.Sequential:
    """1×1 convolutions over [scene features, tiled target features, (similarity, correlation)]: `inputs`
    channels -> `channels`."""
    return nn.Sequential(
        nn.Conv2d(inputs, channels, 1),
        nn.ReLU(inplace=True),
        nn.Conv2d(channels, channels, 1),
        nn.ReLU(inplace=True),
    )


class _Registrations:
    """How many parameters, buffers and submodules any module in this process has registered (torch's global
    registration hooks): `OneShotFCN._weights_key` lists its tensors again only when this count moves, since
    walking the module tree at every `predict` cost ~0.24 ms of a ~2.5 ms call."""

    count = 0

    @classmethod
    def seen(cls, module, name, value):
        cls.count += 1  # returning None keeps what was registered


for _register in (
    nn.modules.module.register_module_parameter_registration_hook,
    nn.modules.module.register_module_buffer_registration_hook,
    nn.modules.module.register_module_module_registration_hook,
):
    _register(_Registrations.seen)


class OneShotFCN(nn.Module):
    """Scene (N, 3, H, W) and target (N, 3, h, w) float images -> class scores (N, 2, H, W)."""

    def __init__(self, config: FCNConfig = FCNConfig()):
        super().__init__()
        self.config = config
        c1, c2, c3 = config.channels
        self.encoder = nn.ModuleList(
            [
                nn.Sequential(_conv(3, c1, 2)),
                nn.Sequential(_conv(c1, c2, 2), _conv(c2, c2)),
                nn.Sequential(_conv(c2, c3, 2), _conv(c3, c3)),
            ]
        )
        self.fuse = nn.ModuleList([_fuse(c, self._fuse_inputs(c, depth)) for depth, c in enumerate(config.channels)])
        self.up3 = nn.ConvTranspose2d(c3, c2, 4, 2, 1)  # 1/8 -> 1/4
        self.up2 = nn.ConvTranspose2d(c2, c1, 4, 2, 1)  # 1/4 -> 1/2
        f = config.full_res_channels
        self.up1 = nn.ConvTranspose2d(c1, f or 2, 4, 2, 1)  # 1/2 -> 1: the two class scores (or f features)
        if f:
            self.full_res = _conv(3, f)
            self.head = nn.Conv2d(f, 2, 3, 1, 1)
        if config.presence_head:
            self.presence = nn.Sequential(nn.Linear(2 * c3, 32), nn.ReLU(inplace=True), nn.Linear(32, 1))
        self.verifier = CandidateVerifier(config.verifier_crop) if config.verifier_crop else None
        self._cached_target: tuple | None = None  # (weights' key, target, its features): `predict`'s cache
        self._runtime_cache: tuple | None = None  # (weights' key, {graph, shapes: session}): fcn_runtime's
        self._cached_verifier_target: tuple | None = None  # (weights' key, target, its verifier encoding)
        self._weight_tensors: tuple | None = None  # (registration count, parameters and buffers): `_weights_key`'s

    def __getstate__(self):  # copies and pickles leave the ONNX Runtime sessions behind (they cannot be copied)
        return {**super().__getstate__(), "_runtime_cache": None, "_weight_tensors": None}

    def encode(self, images: torch.Tensor) -> list[torch.Tensor]:
        features = []
        for block in self.encoder:
            images = block(images)
            features.append(images)
        return features

    def _fuse_inputs(self, channels: int, depth: int) -> int:
        """Channels into depth `depth`'s fusion: the scene's, the target's vector (2x for "masked": mean and
        max), the similarity map ("masked") and the shape kernel's response (at 1/4 and 1/8)."""
        masked = self.config.target_pooling == "masked"
        correlated = self.config.shape_kernel and depth > 0
        return channels * (3 if masked else 2) + masked + (channels if correlated else 0)

    def target_features(self, target: torch.Tensor) -> list[torch.Tensor]:
        """What the scene is matched against, as a flat list of tensors (the ONNX graph's inputs): one vector
        (N, C or 2C, 1, 1) per depth; with `shape_kernel` k, then a kernel (N, C, k, k) for 1/4 and for 1/8."""
        features = self.encode(target)
        if self.config.target_pooling == "max":
            vectors = [t.amax((2, 3), keepdim=True) for t in features]
        else:
            pixels = target_pixels(target).unsqueeze(1).float()
            pixels = torch.where(pixels.flatten(1).any(1).view(-1, 1, 1, 1), pixels, torch.ones_like(pixels))
            vectors = []
            for t in features:
                weight = F.adaptive_avg_pool2d(pixels, t.shape[2:])  # share of target pixels under each cell
                mean = (t * weight).sum((2, 3), keepdim=True) / weight.sum((2, 3), keepdim=True).clamp_min(1e-6)
                vectors.append(torch.cat([mean, (t * (weight > 0)).amax((2, 3), keepdim=True)], 1))
        if not self.config.shape_kernel:
            return vectors
        grid = _box_grid(target, 2 * self.config.shape_kernel)
        kernels = [F.avg_pool2d(F.grid_sample(t, grid, align_corners=False), 2) for t in features[1:]]
        return vectors + kernels

    def segment(self, scene: torch.Tensor, target_features: list[torch.Tensor]) -> torch.Tensor:
        """Class scores (N, 2, H, W) of scenes given their targets' `target_features`."""
        return self.segment_with_presence(scene, target_features)[0]

    def segment_with_presence(
        self, scene: torch.Tensor, target_features: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(class scores (N, 2, H, W), presence logits (N,) or None without `presence_head`)."""
        vectors = target_features[:3]
        kernels = [None, *target_features[3:]] if self.config.shape_kernel else [None] * 3
        fused = []
        for fuse, s, t, kernel in zip(self.fuse, self.encode(scene), vectors, kernels):
            parts = [s, t.expand(-1, -1, *s.shape[2:])]
            if self.config.target_pooling == "masked":
                mean = t[:, : s.shape[1]]
                parts.append(F.cosine_similarity(s, mean.expand_as(s), dim=1, eps=1e-6).unsqueeze(1))
            if kernel is not None:
                parts.append(_correlate(s, kernel))
            fused.append(fuse(torch.cat(parts, 1)))
        x = F.relu(self.up3(fused[2]) + fused[1])
        x = F.relu(self.up2(x) + fused[0])
        x = self.up1(x)
        if self.config.full_res_channels:
            x = self.head(F.relu(x + self.full_res(scene)))
        presence = None
        if self.config.presence_head:
            deepest = fused[2]
            presence = self.presence(torch.cat([deepest.amax((2, 3)), deepest.mean((2, 3))], 1))[:, 0]
        return x, presence

    def forward(self, scene: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return self.segment(scene, self.target_features(target))

    def network_alone(self) -> OneShotFCN:
        """A copy of the segmentation network without its verifier, in eval mode: the candidates' source (and
        the paper's design)."""
        network = OneShotFCN(dataclasses.replace(self.config, verifier_crop=0)).eval()
        network.load_state_dict({k: v for k, v in self.state_dict().items() if not k.startswith("verifier.")})
        return network

    def _weights_key(self) -> tuple:
        """Which weights (and config: a new `presence_threshold`) the model holds: any in-place change of a
        parameter or buffer (an optimiser step, `load_state_dict`) bumps its `_version`, a replaced one has a
        new address; the list of tensors is kept until some module registers a tensor or layer
        (`_Registrations`). Keys `predict`'s caches."""
        if self._weight_tensors is None or self._weight_tensors[0] != _Registrations.count:  # a tensor or layer
            self._weight_tensors = (_Registrations.count, (*self.parameters(), *self.buffers()))  # (re)placed
        return (self.config, *((p.data_ptr(), p._version) for p in self._weight_tensors[1]))

    def _per_target(self, slot: str, target: torch.Tensor, weights: tuple, compute):
        """`compute()`, reusing the last call's (kept in attribute `slot`) while the target images and the weights
        (`_weights_key`) are the same: an episode shows one target image at every step, so what depends only on
        it is computed once."""
        cached = getattr(self, slot)
        if (
            cached is None
            or cached[0] != weights
            or cached[1].shape != target.shape
            or not torch.equal(cached[1], target)
        ):
            cached = (weights, target.clone(), compute())
            setattr(self, slot, cached)
        return cached[2]

    def _target_features_cached(self, target: torch.Tensor, weights: tuple) -> list[torch.Tensor]:
        """`target_features` of the target images, computed once per target (`_per_target`)."""
        return self._per_target("_cached_target", target, weights, lambda: self.target_features(target))

    def scene_outputs(
        self, scene_rgb: torch.Tensor, target_features: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(class scores (N, 2, H, W), presence logits (N,) or None) of checked uint8 scenes (N, H, W, 3) given
        their targets' features, as `predict` computes them: normalise, resize to the training size, segment,
        scores back to the scene's size."""
        height, width = scene_rgb.shape[1:3]
        scene = normalize_images(scene_rgb)
        size = self.config.segment_size or self.config.image_size
        if (height, width) != (size, size):
            if height == width and height % size == 0:  # a whole factor: average its blocks ("area", faster)
                scene = F.avg_pool2d(scene, height // size)
            else:
                scene = F.interpolate(scene, size=(size, size), mode="area" if height > size else "bilinear")
        scores, presence = self.segment_with_presence(scene, target_features)
        if (height, width) != (size, size):
            scores = F.interpolate(scores, size=(height, width), mode="bilinear")
        return scores, presence

    def scene_scores(self, scene_rgb: torch.Tensor, target_features: list[torch.Tensor]) -> torch.Tensor:
        """The class scores of `scene_outputs`."""
        return self.scene_outputs(scene_rgb, target_features)[0]

    def scene_mask(
        self, scene_rgb: torch.Tensor, target_features: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`predict`'s (mask (N, H, W) bool before `largest_component`, presence probability (N,)) from
        `scene_outputs`: with `presence_head`, the mask is empty where the presence is under the threshold;
        without it, the presence is 1 where the mask is not empty. Tensor operations only: this is the graph
        that `fcn_runtime` exports for ONNX Runtime."""
        scores, presence = self.scene_outputs(scene_rgb, target_features)
        mask = scores[:, 1] > scores[:, 0]
        if presence is None:
            return mask, mask.flatten(1).any(1).float()
        presence = presence.sigmoid()
        return mask & (presence >= self.config.presence_threshold).view(-1, 1, 1), presence

    def predict(self, scene_rgb, target_rgb, largest_component: bool = False, runtime: str = "auto") -> torch.Tensor:
        """Target mask (N, H, W) bool of uint8 scenes (N, H, W, 3) given uint8 target images (N, h, w, 3);
        with `largest_component`, only each mask's largest connected region is kept (`boxes.largest_component`;
        with a verifier, the region it finds most probable). Empty where the model judges the target absent
        (`predict_with_presence` gives that score too)."""
        return self.predict_with_presence(scene_rgb, target_rgb, largest_component, runtime)[0]

    @torch.inference_mode()
    def predict_with_presence(
        self,
        scene_rgb,
        target_rgb,
        largest_component: bool = False,
        runtime: str = "auto",
        previous: torch.Tensor | None = None,
        thresholds: tuple[float, float] = (0.0, 0.0),
        border_bar_near_previous: bool = False,
        track_below: float = 0.0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(`predict`'s mask, presence probability (N,)): the presence head's "target in view" probability, or
        for a model without one 1.0 where the mask is not empty and 0.0 where it is.

        With a verifier, `thresholds` = (acquire, track) are the verifier probabilities a region needs: a new
        one, and one near the region kept at the previous step (`previous` (N, H, W) bool, that step's masks
        for the same episodes; `verifier.near_previous`); 0 is the checkpoint's `verifier_threshold`. Tracking
        (a high bar to acquire, a lower one to keep) holds the target through frames where its score dips,
        and makes a look-alike's single high score on one frame rarer to act on. `border_bar_near_previous`: a
        region cut by the image's border gets the verifier's low bar for such regions (`verifier_cut_threshold`) only
        near the previous step's region, in images that have one; elsewhere it needs the acquire bar (a look-alike
        entering by one border while the target is tracked at another is not taken up at the low bar).
        `track_below` (a share of the image, 0: off): the track bar only for regions smaller than that; a larger one
        near the previous region needs the acquire bar too. Up close the verifier tells the target from a look-alike
        (on `dqn.pt`'s frames of two held-out sets, regions of 5% of the image or more score under 0.97 on 0.2% of the
        target's frames and 98% of the look-alikes'), so one tracked from afar is dropped once approached
        (docs/control.md §36).

        `runtime`: "torch" runs the model eagerly; "onnxruntime" runs the same graphs (network and verifier)
        exported from the current weights (`fcn_runtime`: 2-4x faster at batch 1, masks equal up to float
        rounding); "auto" (default) is "onnxruntime" for a model in eval mode on the CPU when it is installed,
        else "torch"."""
        if runtime not in RUNTIMES:
            raise ValueError(f"runtime {runtime!r} is not one of: {', '.join(RUNTIMES)}")
        check_thresholds(thresholds)
        if not 0 <= track_below < 1:
            raise ValueError(f"track_below={track_below!r} must be in [0, 1) (0: off): a share of the image")
        scene = uint8_images(scene_rgb, "scene_rgb")
        target = uint8_images(target_rgb, "target_rgb")
        if len(scene) != len(target):
            raise ValueError(
                f"scene_rgb has {len(scene)} images but target_rgb has {len(target)}: one target per scene"
            )
        height, width = scene.shape[1:3]
        if height % 8 or width % 8:
            raise ValueError(f"scene_rgb is {height}x{width}: sides must be multiples of 8")
        if previous is not None and tuple(previous.shape) != (len(scene), height, width):
            raise ValueError(f"previous has shape {tuple(previous.shape)}, expected {(len(scene), height, width)}")
        device = next(self.parameters()).device
        target = normalize_images(target.to(device))
        if target.shape[2:] != (self.config.target_size,) * 2:
            target = F.interpolate(target, size=(self.config.target_size,) * 2, mode="bilinear")
        weights = self._weights_key()
        features = self._target_features_cached(target, weights)
        outputs = None
        if self._on_onnxruntime(runtime, device):
            outputs = fcn_runtime.scene_mask(self, scene, features, weights, required=runtime == "onnxruntime")
        if outputs is None:  # the plain torch path (or the export failed under "auto": fcn_runtime warned)
            outputs = self.scene_mask(scene.to(device), features)
        mask, presence = outputs
        if self.verifier is not None:  # with `largest_component`, the most probable region: the one kept
            mask, presence = self.verify(
                scene.to(device),
                target,
                mask,
                weights,
                best_only=largest_component,
                previous=previous,
                thresholds=thresholds,
                border_bar_near_previous=border_bar_near_previous,
                track_below=track_below,
                runtime=runtime,
            )
            return mask, presence
        return (keep_largest_component(mask) if largest_component else mask), presence

    def _on_onnxruntime(self, runtime: str, device: torch.device) -> bool:
        """Whether `runtime` ("auto", "onnxruntime" or "torch") runs the graphs through ONNX Runtime."""
        return runtime == "onnxruntime" or (
            runtime == "auto" and device.type == "cpu" and not self.training and fcn_runtime.available()
        )

    def verify(
        self,
        scene_rgb: torch.Tensor,
        target: torch.Tensor,
        mask: torch.Tensor,
        weights: tuple,
        best_only: bool = False,
        previous: torch.Tensor | None = None,
        thresholds: tuple[float, float] = (0.0, 0.0),
        border_bar_near_previous: bool = False,
        track_below: float = 0.0,
        runtime: str = "auto",
    ):
        """(mask of the candidate regions the verifier accepts (with `best_only`, the most probable of them),
        the best region's probability (N,)) of uint8 scenes (N, H, W, 3), normalised targets (N, 3, h, w) and
        the segmentation's masks (N, H, W); `weights` is `_weights_key()` (keys the target crop's encoding);
        `previous`, `thresholds`, `border_bar_near_previous`, `track_below`: `predict_with_presence`'s; `runtime` as there (the
        crops and the target's encoding stay torch's)."""
        if not mask.any():  # no candidate region in any image (~40% of an episode's frames): nothing to verify
            return torch.zeros_like(mask, device=scene_rgb.device), torch.zeros(len(mask), device=scene_rgb.device)
        candidates = candidate_crops(
            normalize_images(scene_rgb), mask.cpu().numpy(), self.config.verifier_regions, self.config.verifier_crop
        )
        logits = self.candidate_logits(target, candidates, weights, runtime)
        acquire, track = (t or self.config.verifier_threshold for t in thresholds)
        threshold = torch.full_like(logits, acquire)
        if previous is not None:
            previous = previous.to(logits.device)
            near = near_previous(candidates["boxes"], candidates["image"], previous)
            threshold[near] = track
            if track_below:  # up close, the acquire bar again
                large = candidates["sizes"].to(logits.device) >= track_below * mask.shape[1] * mask.shape[2]
                threshold[near & large] = acquire
        if self.config.verifier_cut_share:
            cut = cut_regions(candidates, mask.shape[1:], self.config.verifier_cut_share).to(logits.device)
            if border_bar_near_previous and previous is not None:  # images that track nothing keep the low bar
                cut &= near | ~previous.flatten(1).any(1)[candidates["image"]]
            threshold[cut] = threshold[cut].clamp(max=self.config.verifier_cut_threshold)
        mask, presence = keep_verified(candidates, logits.sigmoid(), threshold, len(scene_rgb), best_only)
        return mask.to(scene_rgb.device), presence.to(scene_rgb.device)

    def candidate_logits(
        self, target: torch.Tensor, candidates: dict, weights: tuple | None = None, runtime: str = "auto"
    ) -> torch.Tensor:
        """The verifier's logits (M,) of `candidates` (`verifier.candidate_crops`) against normalised targets
        (N, 3, h, w); with `verifier_mirror`, the mean of those of the crops as they are and mirrored. `weights`
        is `_weights_key()` (keys the target crop's encoding; computed when not given); `runtime` as
        `predict_with_presence`'s."""
        weights = self._weights_key() if weights is None else weights
        mirror = self.config.verifier_mirror
        encoded = self._per_target(
            "_cached_verifier_target",
            target,
            weights,
            lambda: self.verifier.encoder(
                mirrored(target_crops(target, target_pixels(target), self.config.verifier_crop), mirror)
            ),
        )
        images = candidates["image"]
        if mirror:  # the target's two encodings, then every candidate's crop and its mirror image, in one batch
            images = torch.cat([images, images + len(target)])
        target_encoded, crops, logits = encoded[images], mirrored(candidates["scene_crops"], mirror), None
        if self._on_onnxruntime(runtime, target.device):
            logits = fcn_runtime.verifier_logits(self, target_encoded, crops, weights, runtime == "onnxruntime")
        if logits is None:  # the plain torch path (or the export failed under "auto": fcn_runtime warned)
            logits = self.verifier.score(target_encoded, self.verifier.encoder(crops))
        return logits.view(2, -1).mean(0) if mirror else logits


def mirrored(crops: torch.Tensor, mirror: bool) -> torch.Tensor:
    """`crops` (M, C, h, w), followed by the same crops mirrored left-right when `mirror` (2M)."""
    return torch.cat([crops, crops.flip(-1)]) if mirror else crops


def target_pixels(target: torch.Tensor) -> torch.Tensor:
    """(N, h, w) bool: the pixels of normalised target images (N, 3, h, w) that are not the grey background."""
    return (target - TARGET_BACKGROUND).abs().amax(1).gt(0.5 / 255)


def _box_grid(target: torch.Tensor, size: int) -> torch.Tensor:
    """A `grid_sample` grid (N, size, size, 2) over each target image's bounding box of non-grey pixels (the
    whole image if it has none)."""
    pixels = target_pixels(target)
    height, width = pixels.shape[1:]
    rows, cols = pixels.any(2), pixels.any(1)
    steps = [torch.arange(n, dtype=target.dtype, device=target.device) for n in (height, width)]
    boxes = []
    for hits, step, n in ((cols, steps[1], width), (rows, steps[0], height)):
        empty = ~hits.any(1)
        low = torch.where(hits, step, torch.full_like(step, n)).amin(1)
        high = torch.where(hits, step, torch.full_like(step, -1)).amax(1) + 1
        low, high = torch.where(empty, 0, low), torch.where(empty, n, high)
        boxes.append((low / n * 2 - 1, high / n * 2 - 1))  # normalised [-1, 1] edges
    (x0, x1), (y0, y1) = boxes
    t = (torch.arange(size, dtype=target.dtype, device=target.device) + 0.5) / size
    xs = x0[:, None] + (x1 - x0)[:, None] * t  # (N, size)
    ys = y0[:, None] + (y1 - y0)[:, None] * t
    return torch.stack([xs[:, None, :].expand(-1, size, -1), ys[:, :, None].expand(-1, -1, size)], -1)


def _correlate(scene: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Per-sample, per-channel cross-correlation of scene features (N, C, H, W) with kernels (N, C, k, k), odd
    or even k, same size out, divided by k²: a sum of shifted products, so that one graph serves any batch size
    (a grouped convolution would fix the batch in its group count)."""
    k = kernel.shape[-1]
    height, width = scene.shape[2:]
    padded = F.pad(scene, ((k - 1) // 2, k // 2, (k - 1) // 2, k // 2))
    out = 0
    for i in range(k):
        for j in range(k):
            out = out + padded[:, :, i : i + height, j : j + width] * kernel[:, :, i : i + 1, j : j + 1]
    return out / (k * k)


def uint8_images(images, name: str = "images") -> torch.Tensor:
    """uint8 images (N, H, W, 3), numpy or torch -> a uint8 torch tensor (N, H, W, 3); clear errors otherwise."""
    if isinstance(images, np.ndarray):
        images = torch.from_numpy(images)
    if not isinstance(images, torch.Tensor):
        raise TypeError(f"{name} must be a uint8 numpy array or torch tensor (N, H, W, 3), got {type(images).__name__}")
    if images.dtype != torch.uint8:
        raise TypeError(f"{name} must have dtype uint8 (0-255 rgb), got {images.dtype}")
    if images.ndim != 4 or images.shape[-1] != 3:
        hint = " (channels-first? pass channels-last (N, H, W, 3))" if images.ndim == 4 and images.shape[1] == 3 else ""
        raise ValueError(f"{name} must have shape (N, H, W, 3), got {tuple(images.shape)}{hint}")
    return images


def normalize_images(images: torch.Tensor) -> torch.Tensor:
    """uint8 tensor (N, H, W, 3) -> float (N, 3, H, W) in [-0.5, 0.5], the model's input."""
    return images.permute(0, 3, 1, 2).float().div_(255).sub_(0.5)


def images_to_input(images, name: str = "images") -> torch.Tensor:
    """uint8 images (N, H, W, 3), numpy or torch -> float (N, 3, H, W) in [-0.5, 0.5]; clear errors otherwise."""
    return normalize_images(uint8_images(images, name))


def flip_horizontally(*images: torch.Tensor, where: torch.Tensor) -> list[torch.Tensor]:
    """Each of `images` (N, ..., W) with the samples where `where` (N,) bool is true mirrored left-right:
    augmentation that flips a scene, its mask and its target image together (a mirrored scene holds the
    mirrored target)."""
    return [torch.where(where.view((-1,) + (1,) * (x.ndim - 1)), x.flip(-1), x) for x in images]


# ---------------------------------------------------------------- checkpoints
def save_checkpoint(path: str, model: OneShotFCN, **extra) -> None:
    """Weights + config (+ `extra`: plain python values such as metrics and the training arguments)."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    torch.save(dict(format=CHECKPOINT_FORMAT, config=asdict(model.config), state_dict=state, **extra), path)


def load_checkpoint(path: str) -> tuple[OneShotFCN, dict]:
    """(model in eval mode, the checkpoint dict) from `path`, loaded with `weights_only=True`.

    A missing file is FileNotFoundError, an unreadable one or a different model a ValueError naming the path.
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"FCN checkpoint {path!r} does not exist (train one: baselines/train_fcn.py)")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:
        raise ValueError(f"FCN checkpoint {path!r} is not a readable torch checkpoint: {error}") from error
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        found = checkpoint.get("format") if isinstance(checkpoint, dict) else type(checkpoint).__name__
        raise ValueError(f"{path!r} is not an FCN checkpoint: format {found!r}, expected {CHECKPOINT_FORMAT!r}")
    config = dict(checkpoint["config"])
    config["channels"] = tuple(config["channels"])
    model = OneShotFCN(FCNConfig(**config))
    try:
        model.load_state_dict(checkpoint["state_dict"])
    except RuntimeError as error:
        raise ValueError(f"FCN checkpoint {path!r} does not match its config {config}: {error}") from error
    return model.eval(), checkpoint


def load_pretrained(path: str | None = None, segment_size: int = 0) -> OneShotFCN:
    """The shipped, trained FCN (agents/weights/fcn.pt, or `path`), on the CPU in eval mode; with
    `segment_size`, segmenting scenes at that side (`FCNConfig.segment_size`; 0: the checkpoint's)."""
    model, _ = load_checkpoint(path or WEIGHTS_PATH)
    return segmenting_at(model, segment_size) if segment_size else model


def segmenting_at(model: OneShotFCN, segment_size: int) -> OneShotFCN:
    """`model`, changed in place to segment scenes at `segment_size` (`FCNConfig.segment_size`; 0: its training
    size). A bad size is a ValueError naming it."""
    if not (isinstance(segment_size, int) and (segment_size == 0 or segment_size >= 16)):
        raise ValueError(f"segment_size={segment_size!r} must be 0 (the training size) or an integer of at least 16")
    model.config = dataclasses.replace(model.config, segment_size=segment_size)
    return model


# ---------------------------------------------------------------- training and metrics
def class_weights(target_pixel_share: float, power: float = 0.5) -> torch.Tensor:
    """Cross-entropy weights (background, target) against the class imbalance: inverse frequency raised
    to `power` (0.5: the square root, milder than full inverse frequency, which floods the mask with
    false positives), scaled so that background has weight 1."""
    share = min(max(target_pixel_share, 1e-4), 0.5)
    return torch.tensor([1.0, ((1 - share) / share) ** power])


def soft_iou_loss(scores: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """1 - soft IoU (target probability vs true mask), averaged over the samples that contain the target
    (0 if none do): every sample counts the same, whatever its target's size, as in the per-sample IoU."""
    present = mask.flatten(1).any(1)
    if not present.any():
        return scores.sum() * 0
    p = scores[present].softmax(1)[:, 1]
    y = mask[present].float()
    intersection = (p * y).sum((1, 2))
    return (1 - intersection / (p + y - p * y).sum((1, 2)).clamp_min(1e-6)).mean()


def mask_counts(pred: torch.Tensor, mask: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-sample pixel counts (N,) of predicted vs true bool masks (N, H, W): the parts of every metric."""
    if pred.shape != mask.shape or pred.dtype != torch.bool or mask.dtype != torch.bool:
        raise ValueError(
            f"pred and mask must be bool tensors of one shape, got {tuple(pred.shape)} {pred.dtype} and {tuple(mask.shape)} {mask.dtype}"
        )
    return dict(
        intersection=(pred & mask).sum((1, 2)),
        union=(pred | mask).sum((1, 2)),
        correct=(pred == mask).sum((1, 2)),
        predicted=pred.sum((1, 2)),
        true=mask.sum((1, 2)),
        pixels=torch.full((len(mask),), mask[0].numel()),
        box_error=(mask_to_box(pred) - mask_to_box(mask)).abs().mean(1),
    )


def dataset_counts(
    model: OneShotFCN, data: dict, batch_size: int = 64, largest_component: bool = False
) -> dict[str, torch.Tensor]:
    """`mask_counts` of the model's masks over a data set (dict of `scene`, `target`, `mask` arrays)."""
    parts = []
    for i in range(0, len(data["mask"]), batch_size):
        pred = model.predict(data["scene"][i : i + batch_size], data["target"][i : i + batch_size], largest_component)
        parts.append(mask_counts(pred.cpu(), torch.as_tensor(data["mask"][i : i + batch_size])))
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def summarize_counts(counts: dict[str, torch.Tensor]) -> dict[str, float]:
    """pixel_accuracy (all samples); target_iou: mean per-sample IoU over samples that contain the target;
    pooled_target_iou: their summed intersections over summed unions (weights large targets more);
    false_positive_rate: share of samples without the target where anything is predicted;
    fp_pixel_share: predicted pixels per pixel on those samples; box_error: mean absolute error of the
    normalised (x, y, w, h) box on samples with the target; miss_rate: share of those with an empty mask."""
    present = counts["true"] > 0
    absent = ~present
    iou = counts["intersection"][present].float() / counts["union"][present].float()
    nan = float("nan")
    return dict(
        pixel_accuracy=float(counts["correct"].sum() / counts["pixels"].sum()),
        target_iou=float(iou.mean()) if present.any() else nan,
        pooled_target_iou=float(counts["intersection"][present].sum() / counts["union"][present].sum())
        if present.any()
        else nan,
        false_positive_rate=float((counts["predicted"][absent] > 0).float().mean()) if absent.any() else nan,
        fp_pixel_share=float(counts["predicted"][absent].sum() / counts["pixels"][absent].sum())
        if absent.any()
        else nan,
        box_error=float(counts["box_error"][present].mean()) if present.any() else nan,
        miss_rate=float((counts["predicted"][present] == 0).float().mean()) if present.any() else nan,
        samples_with_target=int(present.sum()),
        samples_without_target=int(absent.sum()),
    )


PRESENCE_THRESHOLDS = tuple(round(0.3 + 0.05 * i, 2) for i in range(12))
"""presence thresholds `choose_presence_threshold` tries: 0.30, 0.35, ..., 0.85"""


def choose_presence_threshold(
    model: OneShotFCN, data: dict, thresholds: tuple[float, ...] = PRESENCE_THRESHOLDS, batch_size: int = 64
) -> tuple[float, list[dict]]:
    """The presence threshold with the highest target IoU minus false-positive rate on `data` (validation:
    the same trade-off the best epoch is chosen by), masks as BoxState makes them (largest component); and
    each threshold's metrics. The model's own threshold is left as it is."""
    ungated = dataclasses.replace(model.config, presence_threshold=1e-6)
    kept, model.config = model.config, ungated
    try:
        masks, presence = zip(
            *(
                model.predict_with_presence(data["scene"][i : i + batch_size], data["target"][i : i + batch_size], True)
                for i in range(0, len(data["mask"]), batch_size)
            )
        )
    finally:
        model.config = kept
    masks, presence, true = torch.cat(masks), torch.cat(presence), torch.as_tensor(data["mask"])
    rows = []
    for t in thresholds:
        metrics = summarize_counts(mask_counts(masks & (presence >= t).view(-1, 1, 1), true))
        rows.append(dict(threshold=round(float(t), 3), **metrics))
    best = max(rows, key=lambda r: r["target_iou"] - r["false_positive_rate"])
    return best["threshold"], rows
