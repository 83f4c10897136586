"""Observation wrapper: the env's observation -> the target's bounding box, the low-dimensional state for control.

`source="ground_truth"` takes the box from the wrist camera's segmentation (needs a `segmentation` obs);
`source="projection"` from the task's render-free mask of the target (`render_free=True`, a `state_dict` obs:
its `extra/target_bbox`; nothing is rendered, an approximation: docs/speed.md);
`source="fcn"` from a segmenter (the one-shot FCN, `mani_active_vision.agents.fcn`) on the wrist view and the
target image (needs an `rgb` obs), keeping the mask's largest connected region only (docs/design.md §10).
After every observation `last_mask` holds the mask the box came from, `last_presence` the probability that the
target is in view (the FCN's presence score where it has one; else 1 where the mask is not empty) and
`last_observation` the observation they were computed from, so that a recorder outside this wrapper logs them
with the box. A segmenter that judges the target absent returns an empty mask: the box is zeros, "not seen".
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from mani_active_vision.boxes import mask_stats, mask_to_box

BOX_SOURCES = ("ground_truth", "fcn", "projection")
CANDIDATE_ACQUIRE = 0.99
"""`BoxState(candidate_threshold=)`: the verifier probability a new region needs the step after a candidate. A
look-alike approached as a candidate scores higher as it grows; at the usual acquire bar (0.97) it became the box
in more of the approaches (docs/control.md §34)."""
CANDIDATE_EDGE = 0.05
"""... a candidate is reported only where its box lies this far (a share of the side) inside the image's border:
one- or two-pixel regions at the border come and go as the camera moves."""
CANDIDATE_MIN_PIXELS = 6
"""... and covers at least this many pixels."""


class BoxState(gym.ObservationWrapper):
    """Observation = (x, y, w, h) of the target's box, normalised, zeros when not seen; with
    `with_ee_pos`, the camera's commanded position (x, y, z in m) is appended (the paper's "link state");
    with `with_mask_stats`, then the mask's share of the image and its centroid's offset from the image
    centre (dx, dy as fractions of the width), zeros when unseen: the quantities success is judged on; with
    `with_presence`, the presence score (`last_presence`) before the mask stats, never held: the layout is
    box, [camera position], [presence], [mask stats].

    Batched ManiSkill envs give a torch tensor (N, 4 or 7); a numpy env (`CPUGymWrapper`) gives (4 or 7,).
    `last_mask`: (N, H, W) bool torch tensor, the target mask of the latest observation (ground truth or FCN).
    `segmenter`: for `source="fcn"`, a model with `predict_with_presence(scene_rgb, target_rgb,
    largest_component=True)` -> ((N, H, W) bool, (N,) float), e.g. `agents.fcn.load_pretrained()`
    (`envs.make_env` passes it).
    `thresholds`: for `source="fcn"` with a verifier, (acquire, track): the verifier probability a new region
    needs, and one near the region kept at the previous step of the same episode (0: the checkpoint's
    `verifier_threshold`; `OneShotFCN.predict_with_presence`). (0, 0): every frame judged alone.
    `track_below_area`: with `thresholds`, the track bar only for regions covering less than this share of the image;
    larger ones need the acquire bar (0: off; `OneShotFCN.predict_with_presence(track_below=...)`, docs/control.md §36).
    `hold_steps`: while the mask is empty, the last box seen in the episode is given for up to this many steps
    (the mask and presence stay the source's own; `info["box_held"]` says where the box is a held one); 0: off.
    `hold_follows_camera`: the held box moves as the camera does, as the ground truth's box would: where the box was
    seen, its centre's ray meets the floor (`FLOOR_HEIGHT`, where the objects lie); each held step that point is
    projected with the camera of that step (the observation's `sensor_param`), the box scaled by the ratio of the
    depths, its centre kept within the image (a target that left the view stays at the border it left by, half in
    view), cut to the image; the mask stats follow it (docs/control.md §25).
    `hold_drop_centred`: a held box whose centre has lain within `CENTRED` of the image centre on both axes for more
    than this many held steps in a row is dropped until a box is seen again (0: never): there the target, not cut by
    the border, is seldom missed that long, and a look-alike taken up on one frame is held no further (docs/control.md
    §27).
    `border_bar_near_box`: for `source="fcn"` with `thresholds`, the box tracked from the previous step is the kept
    region or, where the box was a held one, the held box too (its pixels, moved with the camera where it follows it),
    and a region cut by the image's border gets the verifier's low bar only near it
    (`OneShotFCN.predict_with_presence(border_bar_near_previous=True)`): after the target has left by one border, a
    look-alike entering by another needs the acquire bar (docs/control.md §30).
    `candidate_threshold`: for `source="fcn"` with a verifier, where the box is empty (nothing kept, nothing held or
    not), the most probable region the verifier turned away is a candidate if its probability is at least this; its
    box is `info["candidate_box"]` ((N, 4) tensor, or (4,) for a numpy env; zeros where there is none or where it
    lies within `CANDIDATE_EDGE` of the border or covers under `CANDIDATE_MIN_PIXELS`), for the policies to approach
    (`agents.policies.Candidates`), and at the next step a new region needs `CANDIDATE_ACQUIRE` (0: off;
    docs/control.md §34).
    """

    def __init__(
        self,
        env: gym.Env,
        source: str = "ground_truth",
        with_ee_pos: bool = False,
        with_mask_stats: bool = False,
        with_presence: bool = False,
        segmenter=None,
        thresholds: tuple[float, float] = (0.0, 0.0),
        hold_steps: int = 0,
        hold_follows_camera: bool = False,
        hold_drop_centred: int = 0,
        border_bar_near_box: bool = False,
        candidate_threshold: float = 0.0,
        track_below_area: float = 0.0,
    ):
        super().__init__(env)
        check_thresholds(thresholds)
        if source not in BOX_SOURCES:
            raise ValueError(f"source={source!r} is not one of: {', '.join(BOX_SOURCES)}")
        needed = dict(ground_truth="segmentation", fcn="rgb", projection="state_dict")[source]
        if source == "projection" and not getattr(env.unwrapped, "render_free", False):
            raise ValueError("BoxState(source='projection') needs the task made with render_free=True")
        if needed not in env.unwrapped.obs_mode:
            raise ValueError(
                f"BoxState(source={source!r}) needs an obs_mode with {needed}, got {env.unwrapped.obs_mode!r}"
            )
        if hold_follows_camera and (not hold_steps or source == "projection"):
            raise ValueError(
                f"hold_follows_camera moves a held box with the rendered camera: it needs hold_steps > 0 (got "
                f"{hold_steps}) and source ground_truth or fcn (got {source!r})"
            )
        if not (isinstance(hold_drop_centred, int) and hold_drop_centred >= 0) or (
            hold_drop_centred and not hold_steps
        ):
            raise ValueError(
                f"hold_drop_centred={hold_drop_centred!r} must be an integer of at least 0 (0: never), and needs "
                f"hold_steps > 0 (got {hold_steps})"
            )
        if border_bar_near_box and not (source == "fcn" and any(thresholds)):
            raise ValueError(
                "border_bar_near_box restricts the verifier's low bar to the tracked box: it needs source 'fcn' (got "
                f"{source!r}) and thresholds (acquire, track) other than (0, 0), which track it (got {thresholds})"
            )
        if not 0 <= candidate_threshold < 1 or (candidate_threshold and source != "fcn"):
            raise ValueError(
                f"candidate_threshold={candidate_threshold!r} must be in [0, 1) (0: off), and needs source 'fcn' (got "
                f"{source!r}): candidates are regions the FCN's verifier turned away"
            )
        if not 0 <= track_below_area < 1 or (track_below_area and not (source == "fcn" and any(thresholds))):
            raise ValueError(
                f"track_below_area={track_below_area!r} must be in [0, 1) (0: off), and needs source 'fcn' (got "
                f"{source!r}) and thresholds (acquire, track) other than (0, 0) (got {thresholds}): it limits the track bar"
            )
        if source == "fcn" and segmenter is None:
            raise ValueError(
                "BoxState(source='fcn') needs segmenter= (e.g. mani_active_vision.agents.fcn.load_pretrained())"
            )
        self.segmenter = segmenter
        self.last_mask: torch.Tensor | None = None
        self.last_presence: torch.Tensor | None = None
        self.last_observation: dict | None = None
        self.source = source
        self.with_ee_pos = with_ee_pos
        self.with_mask_stats = with_mask_stats
        self.with_presence = with_presence
        self.thresholds = tuple(thresholds)
        self.hold_steps = hold_steps
        self.hold_follows_camera = hold_follows_camera
        self.hold_drop_centred = hold_drop_centred
        self.border_bar_near_box = border_bar_near_box
        self.candidate_threshold = candidate_threshold
        self.track_below_area = track_below_area
        self.last_candidate_box: torch.Tensor | None = None  # (N, 4): this step's candidates as reported (or zeros)
        self._after_candidate: torch.Tensor | None = None  # (N,) bool: the previous step had a candidate
        self._camera: tuple | None = None  # this step's camera: extrinsic, intrinsic (OpenCV axes), image width
        self._seen_camera: tuple | None = None  # the camera where each held box was seen (extrinsic, intrinsic)
        self._held: torch.Tensor | None = None  # (N, 4 or 7): the last box (and mask stats) seen in each episode
        self._unseen_for: torch.Tensor | None = None  # (N,): steps since then
        self._centred_for: torch.Tensor | None = None  # (N,): held steps in a row with the held box centred
        self._held_now: torch.Tensor | None = None  # (N,) bool: the latest observation's box is a held one
        self._held_box: torch.Tensor | None = None  # (N, 4): that held box, where it is one
        dim = 4 + 3 * with_ee_pos + with_presence + 3 * with_mask_stats
        # CPUGymWrapper turns a one-env ManiSkill env into a numpy, unbatched one; keep its convention.
        self._numpy = any(type(e).__name__ == "CPUGymWrapper" for e in _wrapper_chain(env))
        shape = (dim,) if self._numpy else (env.unwrapped.num_envs, dim)
        self.observation_space = gym.spaces.Box(-2.0, 2.0, shape=shape, dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        """The next observation tracks nothing from the episodes being reset (all, or `options["env_idx"]`)."""
        env_idx = (options or {}).get("env_idx")
        self.last_mask = _cleared(self.last_mask, env_idx)
        self._after_candidate = _cleared(self._after_candidate, env_idx)
        if self._held is not None:
            if env_idx is None:
                self._held = self._unseen_for = self._seen_camera = self._centred_for = self._held_now = None
            else:
                self._held[torch.as_tensor(env_idx, device=self._held.device)] = 0.0
                self._centred_for[torch.as_tensor(env_idx, device=self._held.device)] = 0
                self._held_now = self._held_now.clone()
                self._held_now[torch.as_tensor(env_idx, device=self._held.device)] = False
        obs, info = super().reset(seed=seed, options=options)
        return obs, self._with_held(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward, terminated, truncated, self._with_held(info)

    def _with_held(self, info: dict) -> dict:
        """`info` with "box_held" where boxes are held (a bool, or (N,) for batched envs) and "candidate_box" where
        candidates are reported."""
        if self.hold_steps:
            info["box_held"] = bool(self._held_now[0]) if self._numpy else self._held_now
        if self.candidate_threshold:
            info["candidate_box"] = self.last_candidate_box[0].numpy() if self._numpy else self.last_candidate_box
        return info

    def observation(self, obs):
        base = self.env.unwrapped
        batch = (lambda x: torch.as_tensor(x)[None]) if self._numpy else torch.as_tensor
        self.last_observation = obs
        if self.hold_follows_camera:  # small float64 arrays: numpy is ~3x faster than torch here
            camera = obs["sensor_param"]["hand_camera"]
            width = next(iter(obs["sensor_data"]["hand_camera"].values())).shape[-2]  # (..., H, W, C) images
            extrinsic, intrinsic = (batch(camera[k]).cpu().double().numpy() for k in ("extrinsic_cv", "intrinsic_cv"))
            self._camera = (extrinsic, intrinsic, width)
        if self.source == "projection":
            mask = base.projected_target_mask()  # the same mask the task's info came from this step
            presence = mask.flatten(1).any(1).float()
        elif self.source == "fcn":
            rgb, target = batch(obs["sensor_data"]["hand_camera"]["rgb"]), batch(obs["extra"]["target_image"])
            tracking = {}
            if any(self.thresholds):
                previous = self._tracked_mask() if self.border_bar_near_box else self.last_mask
                tracking = dict(
                    previous=previous,
                    thresholds=self.thresholds,
                    border_bar_near_previous=self.border_bar_near_box,
                    track_below=self.track_below_area,
                )
            if self.candidate_threshold:
                mask, presence = self._segment_after_candidates(rgb, target, tracking)
                self.last_candidate_box = self._candidates(rgb, target, mask, presence)
            else:
                mask, presence = self.segmenter.predict_with_presence(rgb, target, largest_component=True, **tracking)
        else:
            seg = batch(obs["sensor_data"]["hand_camera"]["segmentation"])
            mask = seg[..., 0] == base.target_seg_id.to(seg.device)[:, None, None]
            presence = mask.flatten(1).any(1).float()
        self.last_mask, self.last_presence = mask, presence
        state = mask_to_box(mask)
        if self.with_mask_stats:
            state = torch.cat([state, mask_stats(mask)], -1)
        if self.hold_steps:
            state = self._hold(state)
        if self.with_presence:  # the source's own score, not held
            state = torch.cat([state[:, :4], presence[:, None].to(state), state[:, 4:]], -1)
        if self.with_ee_pos:
            state = torch.cat([state[:, :4], base.agent.controller.target_pos.to(state.device), state[:, 4:]], -1)
        if self._numpy:
            return state[0].cpu().numpy()
        return state

    def _segment_after_candidates(self, rgb, target, tracking: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """`predict_with_presence` as without candidates, but with the acquire bar `CANDIDATE_ACQUIRE` in the envs
        whose previous step had a candidate."""
        raised = self._after_candidate
        if raised is None or not raised.any():
            return self.segmenter.predict_with_presence(rgb, target, largest_component=True, **tracking)
        bars = (CANDIDATE_ACQUIRE, self.thresholds[1])
        if raised.all():
            return self.segmenter.predict_with_presence(
                rgb, target, largest_component=True, **dict(tracking, thresholds=bars)
            )
        mask, presence = self.segmenter.predict_with_presence(rgb, target, largest_component=True, **tracking)
        rows = raised.to(mask.device)
        previous = tracking.get("previous")
        extra = dict(tracking, thresholds=bars, previous=None if previous is None else previous[rows])
        mask[rows], presence[rows] = self.segmenter.predict_with_presence(
            rgb[rows], target[rows], largest_component=True, **extra
        )
        return mask, presence

    def _candidates(self, rgb, target, mask: torch.Tensor, presence: torch.Tensor) -> torch.Tensor:
        """(N, 4) boxes of this step's candidates (`candidate_threshold`), zeros where there is none or where it lies
        near the border or is too small; remembers where there was one, for the next step's acquire bar."""
        empty = ~mask.flatten(1).any(1).cpu()
        wanted = empty & (presence.cpu() >= self.candidate_threshold)
        boxes = torch.zeros(len(mask), 4)
        if not wanted.any():  # most frames: nothing to locate or filter
            self._after_candidate = wanted
            return boxes
        bars = (self.candidate_threshold, self.candidate_threshold)
        rows = wanted.to(mask.device)
        candidate, _ = self.segmenter.predict_with_presence(
            rgb[rows], target[rows], largest_component=True, thresholds=bars
        )
        boxes[wanted] = mask_to_box(candidate.cpu()).float()
        self._after_candidate = boxes[:, 2] > 0
        x, y, w, h = boxes.T
        height, width = mask.shape[1:]
        inside = (
            (x > CANDIDATE_EDGE) & (y > CANDIDATE_EDGE) & (x + w < 1 - CANDIDATE_EDGE) & (y + h < 1 - CANDIDATE_EDGE)
        )
        large = w * h * width * height >= CANDIDATE_MIN_PIXELS
        return torch.where((inside & large)[:, None], boxes, 0.0)

    def _hold(self, box: torch.Tensor) -> torch.Tensor:
        """`box` (with its mask stats), the last one seen in place of an empty one for up to `hold_steps` steps
        (moved with the camera where `hold_follows_camera`)."""
        seen = box[:, 2] > 0
        if self._held is None:
            self._held = torch.zeros_like(box)
            self._unseen_for = torch.zeros(len(box), dtype=torch.long, device=box.device)
            self._centred_for = torch.zeros_like(self._unseen_for)
        if self.hold_follows_camera:
            if self._seen_camera is None:
                self._seen_camera = tuple(np.zeros_like(a) for a in self._camera[:2])
            rows = seen.cpu().numpy()
            for kept, now in zip(self._seen_camera, self._camera[:2]):
                kept[rows] = now[rows]
        self._unseen_for = torch.where(seen, 0, self._unseen_for + 1)
        self._held = torch.where(seen[:, None], box, self._held)
        use = ~seen & (self._unseen_for <= self.hold_steps) & (self._held[:, 2] > 0)
        held = self._held
        if self.hold_follows_camera and use.any():  # only the held rows: another env may have seen nothing yet
            rows = use.cpu().numpy().copy()
            extrinsic, intrinsic, width = self._camera
            old = self._held.cpu().numpy().astype(np.float64)[rows]
            anchor = floor_anchor(old, self._seen_camera[0][rows], self._seen_camera[1][rows], width)
            moved, in_front = moved_box(old, anchor, extrinsic[rows], intrinsic[rows], width)
            held = self._held.clone()
            held[use] = torch.as_tensor(moved).to(held)
            rows[rows] = in_front
            use = torch.as_tensor(rows).to(use.device)
        if self.hold_drop_centred:
            centred = use & ((held[:, :2] + held[:, 2:4] / 2 - 0.5).abs() < CENTRED).all(1)
            self._centred_for = torch.where(centred, self._centred_for + 1, 0)
            dropped = self._centred_for > self.hold_drop_centred
            self._unseen_for = torch.where(dropped, self.hold_steps + 1, self._unseen_for)  # held no more until seen
            use = use & ~dropped
        self._held_now, self._held_box = use, held[:, :4]
        return torch.where(use[:, None], held, box)

    def _tracked_mask(self) -> torch.Tensor | None:
        """The previous step's kept mask with, where that step's box was a held one, the held box's pixels added."""
        mask = self.last_mask
        if mask is None or self._held_now is None or not self._held_now.any():
            return mask
        mask = mask.clone()
        height, width = mask.shape[1:]
        for i in torch.nonzero(self._held_now).flatten().tolist():
            x, y, w, h = self._held_box[i].tolist()
            top, left = int(y * height), int(x * width)
            mask[i, top : max(int((y + h) * height), top + 1), left : max(int((x + w) * width), left + 1)] = True
        return mask


FLOOR_HEIGHT = 0.0
"""The floor's height (m), where the objects lie: a held box's centre is anchored where its ray meets it."""
CENTRED = 0.25
"""`BoxState(hold_drop_centred=)`: how far from the image centre (a fraction of its side, on both axes) a held box's
centre counts as centred: the middle half of the image"""


def _cleared(flags: torch.Tensor | None, env_idx) -> torch.Tensor | None:
    """Per-env bool state (N, ...) with the episodes being reset cleared: None when all are (`env_idx` None), else a
    copy with their rows False."""
    if flags is None or env_idx is None:
        return None
    flags = flags.clone()
    flags[torch.as_tensor(env_idx, device=flags.device)] = False
    return flags


def floor_anchor(box: np.ndarray, extrinsic: np.ndarray, intrinsic: np.ndarray, size: int) -> np.ndarray:
    """(N, 4): where the ray through each box's centre (x, y, w, h normalised, (N, >= 4)) meets the floor (x, y, z,
    world) and its depth in the camera (OpenCV `extrinsic` (N, 3, 4) world -> camera, `intrinsic` (N, 3, 3), a
    `size`² image)."""
    pixel = np.stack([(box[:, 0] + box[:, 2] / 2) * size, (box[:, 1] + box[:, 3] / 2) * size, np.ones(len(box))], -1)
    rotation, translation = extrinsic[:, :, :3], extrinsic[:, :, 3]
    ray = np.einsum("nji,nj->ni", rotation, np.linalg.solve(intrinsic, pixel[..., None])[..., 0])
    centre = -np.einsum("nji,nj->ni", rotation, translation)
    point = centre + ((FLOOR_HEIGHT - centre[:, 2]) / ray[:, 2])[:, None] * ray
    depth = np.einsum("nj,nj->n", rotation[:, 2], point) + translation[:, 2]
    return np.concatenate([point, depth[:, None]], -1)


def moved_box(held: np.ndarray, anchor: np.ndarray, extrinsic: np.ndarray, intrinsic: np.ndarray, size: int):
    """(the held boxes, with their mask stats, moved to where their anchors project now; (N,) bool: the anchor is in
    front of the camera, as it was when seen). The box is scaled by the ratio of the depths; its centre is kept within
    the image and the box cut to it; the mask's share scales with the box's area kept, its centroid moves with the
    centre."""
    camera = np.einsum("nij,nj->ni", extrinsic[:, :, :3], anchor[:, :3]) + extrinsic[:, :, 3]
    depth = np.maximum(camera[:, 2], 1e-3)
    centre = np.clip(np.einsum("nij,nj->ni", intrinsic, camera / depth[:, None])[:, :2] / size, 0, 1)
    scale = anchor[:, 3] / depth
    width, height = held[:, 2] * scale, held[:, 3] * scale
    x0, y0 = np.clip(centre[:, 0] - width / 2, 0, 1), np.clip(centre[:, 1] - height / 2, 0, 1)
    x1, y1 = np.clip(centre[:, 0] + width / 2, 0, 1), np.clip(centre[:, 1] + height / 2, 0, 1)
    moved = np.stack([x0, y0, x1 - x0, y1 - y0], -1)
    if held.shape[1] > 4:  # the mask stats: share, centroid offset
        kept = (x1 - x0) * (y1 - y0) / np.maximum(width * height, 1e-9)
        offset = held[:, 5:7] + centre - np.stack([held[:, 0] + held[:, 2] / 2, held[:, 1] + held[:, 3] / 2], -1)
        moved = np.concatenate([moved, (held[:, 4] * scale**2 * kept)[:, None], offset], -1)
    return moved, (camera[:, 2] > 0.01) & (anchor[:, 3] > 0.01)  # a ray above the horizon meets no floor


def check_thresholds(thresholds) -> None:
    """The verifier's (acquire, track) probabilities, each in [0, 1), 0 the checkpoint's; else a ValueError."""
    if len(thresholds) != 2 or not all(0 <= t < 1 for t in thresholds):
        raise ValueError(f"thresholds={thresholds} must be (acquire, track), each in [0, 1) (0: the checkpoint's)")


def _wrapper_chain(env):
    while isinstance(env, gym.Wrapper):
        yield env
        env = env.env
    yield env
