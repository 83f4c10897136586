"""One env config and one way to build an env from it (docs/design.md §2).

    config = EnvConfig(box_source="fcn", object_set="unseen")
    env = make_env(config)                # ActiveVisionFind-v0 -> DiscreteDirections -> BoxState
    env = RerunRecorder(make_env(config), "recordings/run.rrd")   # recorded (mani_active_vision.recording)

Scripts nest `EnvConfig` in their arguments (`--env.object-set unseen`), DQN checkpoints store it, and
evaluation reads it back from them. A new env option is a field here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gymnasium as gym

import mani_active_vision.tasks.active_vision_find  # noqa: F401  (registers ActiveVisionFind-v0)
from mani_active_vision.agents.fcn import load_pretrained
from mani_active_vision.box_state import BOX_SOURCES, BoxState
from mani_active_vision.directions import FINE_AREA, FINE_NEAR_CENTRE, DiscreteDirections, check_direction_options

ENV_ID = "ActiveVisionFind-v0"
BOX_SOURCE_CHOICES = (*BOX_SOURCES, "none")


FCN_IMAGE_SIZE = 128
"""The wrist camera's side where the FCN's box is deployed: its verifier compares the outline of each candidate
with the target image's at the camera's own resolution, so a 64² camera halves what it sees (the servo on the
FCN's box: 0.58 success at 128², 0.24 at 64²; docs/vision.md). Training on the ground-truth box keeps 64²."""

FCN_BOX_HOLD_STEPS = 20
"""`EnvConfig.box_hold_steps` where the FCN's box is deployed: an agent trained on the ground-truth box keeps
acting on the last box the FCN saw while the FCN misses the target (docs/control.md §6)."""

DQN_FCN_THRESHOLDS = (0.97, 0.9)
"""`EnvConfig.fcn_acquire_threshold`, `fcn_track_threshold` where the shipped DQN is deployed: a new region
needs the verifier's 0.97 to become the box, one near the last box keeps it at the FCN's own 0.9, so fewer
look-alikes are taken for the target (docs/control.md §7; `baselines/ship_dqn.py`, the demo)."""

FCN_SEGMENT_SIZE = 128
"""`EnvConfig.fcn_segment_size` where the shipped DQNs are deployed: the network segments the camera's own 128²
instead of the 64² it learnt at, so a target seen small keeps its pixels (success +0.04 to +0.05 on four held-out
sets for the shipped preset's five networks, for ~2 ms more per frame: docs/control.md §17, docs/vision.md)."""

DQN_FINE_STEP_SIZE = 0.025
"""`EnvConfig.fine_step_size` where the shipped DQN learns and is deployed (the `hold_stay_fine` preset): close to
the target it takes half steps, which land on views in success that the full step passes over (docs/control.md
§11, §12; `baselines/ship_dqn.py`, the demo)."""

DQN_FINE_NEAR_CENTRE = 0.2
"""`EnvConfig.fine_near_centre` where the shipped DQNs are deployed: the fine moves only while the box's centre is
within 0.2 of the image centre (0.3 in training). A push leaves the target off centre, and at half steps the way
back does not fit in 20 steps; with the full step there, recovery after a 6-step push rises from 0.86 to 0.92 for
the shipped preset's five networks (docs/control.md §18)."""

DQN_FINE_FROM_AREA = 0.045
"""`EnvConfig.fine_from_area` where the shipped DQNs are deployed: the fine moves once the box covers 4.5% of the
image (2% in training). From 2% the approach takes half steps long before a full step could pass over a view in
success; from 4.5% the five networks reach success about 3 steps sooner (SPL +0.04 on four sets), success the same;
from 6% some small targets are passed over again (docs/control.md §32)."""

DQN_BACK_WHEN_CLOSE = 0.2
"""`EnvConfig.back_when_close` where the shipped DQNs are deployed: a step backward (zoom out) while the box is cut
by the image's border and covers a fifth of the image or more. A push forward leaves the target that close and cut,
a view the networks never learnt from (they stay or cycle there); with the step back their recovery after a
6-step push rises from 0.92 to 0.95 and 0.96 on two sets (0.90 to 0.91 on a third, where sideways pushes fail
most), success unchanged or higher (docs/control.md §19); on the first set 0.96 once it acts only on a box seen at
that step, not a held one (§20)."""

DQN_EXPLORE_RESUMES_AFTER = 5
"""`EnvConfig.explore_resumes_after` where the shipped DQNs are deployed: once the box has been empty (nothing seen,
nothing held) for 5 steps after the hand-over, the scripted exploration orbits again until the next sighting. A
hand-over on a look-alike otherwise leaves the network acting on an empty box to the episode's end (docs/control.md
§31)."""
DQN_FCN_CANDIDATE_THRESHOLD = 0.9
"""`EnvConfig.fcn_candidate_threshold` where the shipped DQNs are deployed: a region the verifier turned away with a
probability of 0.9 or more is a candidate that the exploration (and the servo) approach to see it larger. A target
seen small (~10-20 pixels) scores 0.9-0.97 and is otherwise passed over by the orbit; over nine held-out sets the
shipped preset's five networks' SPL rises by 0.019 and the servo's by 0.017 (docs/control.md §34)."""
DQN_BOX_HOLD_DROP_CENTRED = 4
"""`EnvConfig.box_hold_drop_centred` where the shipped DQNs are deployed: a held box centred in the image for more than
4 held steps in a row, nothing seen there, is dropped. A look-alike the FCN takes up on one frame is otherwise held
for 20 steps and followed to the middle of the view, while the target leaves it; dropped, the shipped preset's five
networks succeed in 915 of 1,000 held-out episodes over four sets (907 before), recovery unchanged (docs/control.md §27)."""


@dataclass(frozen=True)
class EnvConfig:
    """Every option of the env a script or a checkpoint needs (the task's own are checked by the task)."""

    num_objects: int = 5
    """objects on the floor, 1-8; the first is the target"""
    object_set: str = "train"
    """train (random_urdfs 000-799), unseen (800-999 + named models) or primitives"""
    placement: str = "random"
    """random, or fixed (the same scene every episode: the paper's first experiment)"""
    start_pose: str = "sky"
    """sky (pointing up, the paper's) or search (camera at radius 0.30 m, height 0.90 m)"""
    step_size: float = 0.05
    """metres per discrete step, at most 0.1"""
    success_fraction: float = 0.05
    """the target's share of the image needed for success (docs/design.md §6)"""
    success_center_tol: float = 0.15
    """largest distance of the target's centroid from the image centre, as a fraction of the width"""
    terminate_on_success: bool = False
    """end the episode at the first success (the paper's agent keeps its focus: off)"""
    reward_mode: str = "dense"
    """dense (the target's share of the image: the paper's), normalized_dense or sparse"""
    image_size: int = 64
    """side of the wrist camera image in pixels (the task's own default is 128; with box_source=fcn use
    FCN_IMAGE_SIZE = 128, as the demo and the shipped agents do)"""
    target_image_size: int = 64
    """side of the target image in pixels"""
    max_episode_steps: int = 100
    """steps before an episode is truncated"""
    box_source: str = "ground_truth"
    """the box state: ground_truth (segmentation), fcn (the one-shot FCN on rgb), projection (the target's hull
    projected, nothing rendered: for state-based training, an approximation; docs/speed.md) or none (raw
    observations)"""
    fcn_weights: str = ""
    """FCN checkpoint for box_source=fcn (empty: the shipped agents/weights/fcn.pt)"""
    fcn_segment_size: int = 0
    """box_source=fcn: the side the FCN segments the camera image at (0: the checkpoint's training size, 64²);
    FCN_SEGMENT_SIZE = 128, the camera's own, keeps small targets' pixels (docs/vision.md)"""
    fcn_acquire_threshold: float = 0.0
    """box_source=fcn: the verifier probability a new region needs to become the box (0: the checkpoint's
    `verifier_threshold`)"""
    fcn_track_threshold: float = 0.0
    """box_source=fcn: the verifier probability a region near the previous step's box needs to stay the box
    (0: the checkpoint's `verifier_threshold`); below the acquiring one, the box tracks the target"""
    fcn_candidate_threshold: float = 0.0
    """box_source=fcn with a verifier: where the box is empty, the most probable region the verifier turned away, if its
    probability is at least this, is a candidate: `info["candidate_box"]` gives its box where it lies inside the image
    (`box_state.CANDIDATE_EDGE`) and covers `box_state.CANDIDATE_MIN_PIXELS` or more, and the next step a new region
    needs `box_state.CANDIDATE_ACQUIRE` to become the box. The exploration and the servo approach a candidate for a
    few steps (`agents.policies.Candidates`) to see it larger (0: off; the shipped DQNs are deployed with
    DQN_FCN_CANDIDATE_THRESHOLD; docs/control.md §34)"""
    box_hold_steps: int = 0
    """while the box source sees nothing, keep giving the last box seen in the episode for up to this many
    steps (0: off): the FCN misses a third of the target's views, mostly small or cut ones (docs/control.md)"""
    box_hold_drop_centred: int = 0
    """with box_hold_steps, a held box whose centre has stayed in the middle half of the image for more than this many
    held steps in a row, nothing seen, is dropped until a box is seen again (0: never). The shipped DQNs are deployed
    with DQN_BOX_HOLD_DROP_CENTRED (docs/control.md §27)"""
    box_hold_follows_camera: bool = False
    """with box_hold_steps, the held box moves as the camera does (as the ground truth's box would), anchored where
    its centre's ray met the floor, and stays at the image's border once the target has left by it; off: it stays
    where it was last seen. The shipped DQNs are deployed with it (docs/control.md §25)"""
    fcn_track_below_area: float = 0.0
    """box_source=fcn with the verifier's bars: the track bar only for regions covering less than this share of the
    image; a larger region, even near the tracked box, needs the acquire bar (0: off; other box sources: no effect).
    Up close the verifier tells a look-alike from the target, so one tracked from afar is dropped once approached
    (docs/control.md §36; not in the deployment)"""
    fcn_border_bar_near_box: bool = False
    """box_source=fcn with the verifier's bars: a region cut by the image's border gets the verifier's low bar for
    such regions only near the previous step's box, kept or held; elsewhere it needs the acquire bar, so that a
    look-alike entering by one border after the target left by another is not taken up (other box sources: no
    effect). The shipped DQNs are deployed with it (docs/control.md §30)"""
    with_ee_pos: bool = False
    """append the camera's commanded position to the box (the paper's "link state")"""
    with_mask_stats: bool = False
    """append, after the camera's position, the box source's mask's share of the image and its centroid's
    offset from the image centre (dx, dy, fractions of the width; zeros when unseen): what success is judged
    on, which the box alone does not give (docs/search.md)"""
    with_presence: bool = False
    """append, after the camera's position and before the mask stats, the box source's presence score: the FCN's
    probability that the target is in view (its verifier's best region, accepted or not), 1 or 0 for the
    ground truth's box; for the memory agent, which can then remember a glimpse the FCN did not accept
    (docs/search.md)"""
    occluders: int = 0
    """upright panels that hide objects from the search height, one in front of each of the first
    `occluders` objects (0 to num_objects; docs/task.md#occluders)"""
    stay_action: bool = False
    """a seventh action, stay (index 6, a zero step), so that an agent can hold a view (not the paper's:
    its six directions stay the default; docs/control.md)"""
    fine_step_size: float = 0.0
    """the six directions again at this shorter step, as actions after them (and after stay), for the policy
    that takes over from the exploration: a view in success is often one or two of the full step's lattice
    (0: off, the paper's; docs/control.md §11)"""
    fine_near_centre: float = FINE_NEAR_CENTRE
    """with fine_step_size, how far the target's box centre may lie from the image centre (in x and in y, a
    fraction of the side) for the policies to take the fine moves (`agents.policies.near_target`); the shipped
    DQNs are deployed at DQN_FINE_NEAR_CENTRE (docs/control.md §18)"""
    fine_from_area: float = FINE_AREA[0]
    """with fine_step_size, the share of the image the target's box must cover for the policies to take the fine
    moves (up to `directions.FINE_AREA`'s 0.25; `agents.policies.near_target`); the shipped DQNs are deployed at
    DQN_FINE_FROM_AREA (docs/control.md §32)"""
    back_when_close: float = 0.0
    """0: off; > 0: a DQN policy steps backward (zoom out) instead of its choice while the box, seen this step (not
    held), touches the image's border and covers at least this share of the image (`agents.policies.too_close`); the
    shipped DQNs are deployed at DQN_BACK_WHEN_CLOSE (docs/control.md §19–20)"""
    explore_resumes_after: int = 0
    """after the scripted exploration has handed over to a policy (`agents.policies.ExplorePolicy`), once the box
    state has been empty (nothing seen, nothing held) for this many steps in a row, the exploration orbits again until
    the next sighting (0: never, the paper's single hand-over). The shipped DQNs are deployed with
    DQN_EXPLORE_RESUMES_AFTER (docs/control.md §31)"""
    sweep_retraces: bool = False
    """the scripted sweeps (the exploration's and the servo's, `agents.policies.Sweep`) first undo the forward and
    up/down steps taken since they last orbited (an approach to a box that was then lost, e.g. a look-alike's), then
    orbit on: the orbit sees the objects from its own distance again (docs/control.md §36; not in the deployment)"""
    stay_needs_success: bool = False
    """a learned policy with `stay` (the DQN, the memory agent) takes it only where the box source's mask stats say
    the view is in success (its share of the image at least success_fraction, its centroid within
    success_center_tol of the centre, its box not cut by the border); elsewhere it takes its best move. A stay
    leaves the state as it was, so a greedy network that stays off success stays to the episode's end. Needs
    with_mask_stats where stay_action is set; every shipped agent with `stay` is deployed with it
    (`agents.policies.stay_rule`; docs/control.md §21)"""

    def __post_init__(self):
        if self.box_source not in BOX_SOURCE_CHOICES:
            raise ValueError(f"box_source={self.box_source!r} is not one of: {', '.join(BOX_SOURCE_CHOICES)}")
        if self.with_ee_pos and self.box_source == "none":
            raise ValueError("with_ee_pos appends to the box state: it needs box_source ground_truth or fcn")
        if self.with_mask_stats and self.box_source == "none":
            raise ValueError("with_mask_stats appends to the box state: it needs box_source ground_truth or fcn")
        if self.with_presence and self.box_source == "none":
            raise ValueError("with_presence appends to the box state: it needs box_source ground_truth or fcn")
        if not (isinstance(self.image_size, int) and self.image_size >= 8):
            raise ValueError(f"image_size={self.image_size!r} must be an integer of at least 8")
        if not (isinstance(self.fcn_segment_size, int) and (self.fcn_segment_size == 0 or self.fcn_segment_size >= 16)):
            raise ValueError(
                f"fcn_segment_size={self.fcn_segment_size!r} must be 0 (the checkpoint's) or an integer of at least 16"
            )
        for name in ("fcn_acquire_threshold", "fcn_track_threshold"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)!r} must be in [0, 1) (0: the checkpoint's)")
        if not 0 <= self.fcn_track_below_area < 1:
            raise ValueError(f"fcn_track_below_area={self.fcn_track_below_area!r} must be in [0, 1) (0: off)")
        if not 0 <= self.fcn_candidate_threshold < 1:
            raise ValueError(f"fcn_candidate_threshold={self.fcn_candidate_threshold!r} must be in [0, 1) (0: off)")
        if not (isinstance(self.box_hold_steps, int) and self.box_hold_steps >= 0):
            raise ValueError(f"box_hold_steps={self.box_hold_steps!r} must be an integer of at least 0 (0: off)")
        if not (isinstance(self.box_hold_drop_centred, int) and self.box_hold_drop_centred >= 0) or (
            self.box_hold_drop_centred and not self.box_hold_steps
        ):
            raise ValueError(
                f"box_hold_drop_centred={self.box_hold_drop_centred!r} must be an integer of at least 0 (0: never), and "
                f"needs box_hold_steps > 0 (got {self.box_hold_steps})"
            )
        if self.box_hold_follows_camera and not (self.box_hold_steps and self.box_source in ("ground_truth", "fcn")):
            raise ValueError(
                "box_hold_follows_camera moves a held box with the camera: it needs box_hold_steps > 0 (got "
                f"{self.box_hold_steps}) and box_source ground_truth or fcn (got {self.box_source!r})"
            )
        untracked = self.box_source == "fcn" and not (self.fcn_acquire_threshold or self.fcn_track_threshold)
        for name, what in (
            ("fcn_border_bar_near_box", "restricts the verifier's low bar to the tracked box"),
            ("fcn_track_below_area", "limits the verifier's track bar"),
        ):
            if untracked and getattr(self, name):
                raise ValueError(
                    f"{name} {what}: on the FCN's box it needs fcn_acquire_threshold or fcn_track_threshold set, "
                    "which track it (got 0.0, 0.0)"
                )
        check_direction_options(
            self.step_size,
            self.fine_step_size,
            self.fine_near_centre,
            self.fine_from_area,
            self.back_when_close,
            self.explore_resumes_after,
            fine_step_name="fine_step_size",
        )
        if self.stay_needs_success and self.stay_action and not self.with_mask_stats:
            raise ValueError("stay_needs_success judges success from the mask stats: it needs with_mask_stats=True")
        if not (isinstance(self.max_episode_steps, int) and self.max_episode_steps >= 1):
            raise ValueError(f"max_episode_steps={self.max_episode_steps!r} must be a positive integer")

    def task_kwargs(self) -> dict:
        """Keyword arguments of `gym.make(ENV_ID, ...)` for this config (one env, CPU renderer)."""
        return dict(
            obs_mode="state_dict" if self.box_source == "projection" else "rgb+segmentation",
            render_backend="cpu",
            max_episode_steps=self.max_episode_steps,
            sensor_configs=dict(hand_camera=dict(width=self.image_size, height=self.image_size)),
            num_objects=self.num_objects,
            object_set=self.object_set,
            placement=self.placement,
            start_pose=self.start_pose,
            step_size=self.step_size,
            success_fraction=self.success_fraction,
            success_center_tol=self.success_center_tol,
            terminate_on_success=self.terminate_on_success,
            reward_mode=self.reward_mode,
            target_image_size=self.target_image_size,
            occluders=self.occluders,
            render_free=self.box_source == "projection",
        )

    def replace(self, **changes) -> EnvConfig:
        """A copy with `changes`; unknown names are a `TypeError` that lists the valid ones."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            valid = ", ".join(f.name for f in dataclasses.fields(self))
            raise TypeError(f"EnvConfig has no option {', '.join(sorted(unknown))}; options: {valid}")
        return dataclasses.replace(self, **changes)

    def on_fcn_box(self, thresholds: tuple[float, float] | None = None) -> EnvConfig:
        """This config on the FCN's box as the shipped agents are deployed: the camera at `FCN_IMAGE_SIZE`, the box
        held `FCN_BOX_HOLD_STEPS` steps through the FCN's misses; with `thresholds`, the verifier's bars
        (`fcn_acquire_threshold`, `fcn_track_threshold`; e.g. `DQN_FCN_THRESHOLDS`), else this config's."""
        config = self.replace(box_source="fcn", image_size=FCN_IMAGE_SIZE, box_hold_steps=FCN_BOX_HOLD_STEPS)
        if thresholds is None:
            return config
        acquire, track = thresholds
        return config.replace(fcn_acquire_threshold=acquire, fcn_track_threshold=track)

    def as_dqn_deployed(self) -> EnvConfig:
        """This config as the shipped DQNs are deployed: on the FCN's box (`on_fcn_box`) with the verifier's bars
        `DQN_FCN_THRESHOLDS`, the network segmenting at `FCN_SEGMENT_SIZE`, and the fine moves
        (`DQN_FINE_STEP_SIZE`) within `DQN_FINE_NEAR_CENTRE` of the image centre once the box covers
        `DQN_FINE_FROM_AREA` of the image, and a step back when the box is
        cut and `DQN_BACK_WHEN_CLOSE` of the image or more, and `stay` only where the mask stats say success (where the
        state has them to judge by; every preset with `stay` does), and the held box moving with the camera and
        dropped once centred and unseen for `DQN_BOX_HOLD_DROP_CENTRED` steps, and the border's low bar only near the
        tracked box, and the exploration resuming after `DQN_EXPLORE_RESUMES_AFTER` steps of an empty box, and
        candidates from `DQN_FCN_CANDIDATE_THRESHOLD` approached (docs/control.md §12, §17–§21, §25, §27, §30–§32,
        §34)."""
        return (
            self.on_fcn_box(DQN_FCN_THRESHOLDS)
            .with_held_box_tracking()
            .replace(
                fcn_segment_size=FCN_SEGMENT_SIZE,
                fine_step_size=DQN_FINE_STEP_SIZE,
                fine_near_centre=DQN_FINE_NEAR_CENTRE,
                fine_from_area=DQN_FINE_FROM_AREA,
                back_when_close=DQN_BACK_WHEN_CLOSE,
                stay_needs_success=self.with_mask_stats,
                fcn_border_bar_near_box=True,
                explore_resumes_after=DQN_EXPLORE_RESUMES_AFTER,
                fcn_candidate_threshold=DQN_FCN_CANDIDATE_THRESHOLD,
            )
        )

    def with_held_box_tracking(self) -> EnvConfig:
        """This config with the held box moving as the camera does and dropped once centred and unseen for
        `DQN_BOX_HOLD_DROP_CENTRED` held steps, as the shipped DQNs (docs/control.md §25, §27) and the memory agent
        for occluded scenes (docs/task.md#occluders) are deployed."""
        return self.replace(box_hold_follows_camera=True, box_hold_drop_centred=DQN_BOX_HOLD_DROP_CENTRED)

    @classmethod
    def from_dict(cls, options: dict) -> EnvConfig:
        """The config a checkpoint stored (`dataclasses.asdict`); unknown keys are an error."""
        return cls().replace(**options)


def wrap_env(env: gym.Env, config: EnvConfig, segmenter=None) -> gym.Env:
    """`DiscreteDirections`, then `BoxState` as `config` says, around a made task (also inside vector-env
    workers). `segmenter`: the FCN for box_source=fcn, used as it is (default: loaded from `config.fcn_weights`,
    segmenting at `config.fcn_segment_size`)."""
    env = DiscreteDirections(
        env,
        stay_action=config.stay_action,
        fine_step=config.fine_step_size,
        fine_near_centre=config.fine_near_centre,
        fine_from_area=config.fine_from_area,
        back_when_close=config.back_when_close,
        stay_needs_success=config.stay_needs_success,
        explore_resumes_after=config.explore_resumes_after,
        sweep_retraces=config.sweep_retraces,
    )
    if config.box_source == "none":
        return env
    if config.box_source == "fcn" and segmenter is None:
        segmenter = load_pretrained(config.fcn_weights or None, config.fcn_segment_size)
    return BoxState(
        env,
        source=config.box_source,
        with_ee_pos=config.with_ee_pos,
        with_mask_stats=config.with_mask_stats,
        with_presence=config.with_presence,
        segmenter=segmenter,
        thresholds=(config.fcn_acquire_threshold, config.fcn_track_threshold),
        hold_steps=config.box_hold_steps,
        hold_follows_camera=config.box_hold_follows_camera,
        hold_drop_centred=config.box_hold_drop_centred,
        border_bar_near_box=config.fcn_border_bar_near_box and config.box_source == "fcn",
        candidate_threshold=config.fcn_candidate_threshold if config.box_source == "fcn" else 0.0,
        track_below_area=config.fcn_track_below_area if config.box_source == "fcn" else 0.0,
    )


def make_env(config: EnvConfig = EnvConfig(), segmenter=None) -> gym.Env:
    """The project's env: `ActiveVisionFind-v0` (one env, CPU renderer) with the six directions and the
    box state of `config` (and `stay` with `stay_action`). Record it with `mani_active_vision.recording.RerunRecorder(make_env(...), path)`."""
    return wrap_env(gym.make(ENV_ID, **config.task_kwargs()), config, segmenter)
