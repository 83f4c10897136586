"""Why does a policy fail on the FCN's box where it succeeds on the ground truth's? The scripted servo, or the
exploration and then a DQN (`--checkpoint`), runs on both boxes on the same held-out episodes; every episode
solved on the ground truth's box and not on the FCN's is put in one class by what the FCN's box lay on, step
by step (the wrist camera's segmentation names each pixel's object):

- "on a look-alike": the box lay on another object on more steps than on the target (that object's relation
  to the target is counted: same colour, same shape, other);
- "target missed": the target was in view (>= 20 px) and the box was empty on most of those steps;
- "on the target, not reached": the box lay mostly on the target and success never came;
- "target never in view": never >= 20 px of it.

It also prints where the FCN's box costs steps on the episodes both boxes solve: the steps from the target's
first view (>= 20 px) to the box's first appearance (the exploration's hand-over), on each box, and the
episodes whose first box came 10 or more steps after the target's first view (a first glimpse turned away,
so the sweep went round: docs/control.md §7).

    python baselines/box_failures.py --episodes 50 --env.fcn-acquire-threshold 0.97 --env.fcn-track-threshold 0.5
    python baselines/box_failures.py --episodes 50 --checkpoint agents/weights/dqn.pt
    python baselines/box_failures.py --episodes 50 --look-over --env.occluders 2
"""

from __future__ import annotations

import collections
import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from mani_active_vision.agents.policies import make_policy
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.protocol import eval_seeds
from mani_active_vision.evaluation.rollout import run_episode
from mani_active_vision.evaluation.rollout_frames import RELATIONS, object_map, slot_relations
from mani_active_vision.metrics import first_index

SEEN_PX = 20
"""target pixels that count as "in view" """
CLASSES = ("on a look-alike", "target missed", "on the target, not reached", "target never in view")
"""what `classify` calls a lost episode, in the report's order"""
LATE_STEPS = 10
"""a first box this many steps after the target's first view counts as late (the sweep went on past it)"""


@dataclass
class Args:
    episodes: int = 50
    seed: int = 1_000_000
    """first episode's seed (held out)"""
    env: EnvConfig = field(default_factory=lambda: EnvConfig(object_set="unseen").on_fcn_box())
    """the env on the FCN's box, as deployed (with --checkpoint: the checkpoint's env, a shipped agent's being
    the deployed one); the reference is the same with the ground-truth box"""
    checkpoint: str = ""
    """a DQN checkpoint: the policy is the exploration, then this DQN (default: the scripted servo)"""
    look_over: bool = False
    """on scenes with --env.occluders: the sweep first looks over the panels (and the servo approaches from above)"""


def make(env, args: Args):
    """The policy compared: the servo, or the exploration handing over to the DQN of `args.checkpoint`."""
    look_over = {"look_over": True} if args.look_over else {}
    if args.checkpoint:
        return make_policy("explore", env, then="dqn", checkpoint=args.checkpoint, **look_over)
    return make_policy("servo", env, **look_over)


def box_steps(env, policy, seed: int) -> tuple[float, list[dict]]:
    """(steps to success (NaN: none), per observation: target pixels in view, the box's pixels on the target, the object the box
    mostly lies on (slot + 1, 0 floor, or None without a box), the box's presence score) of the policy."""
    box_state, base, steps = env, env.unwrapped, []  # make_env's outermost wrapper is the BoxState

    def note(obs, info):
        segmentation = box_state.last_observation["sensor_data"]["hand_camera"]["segmentation"][0, ..., 0]
        objects = object_map(base, segmentation.cpu().numpy())
        box = box_state.last_mask[0].cpu().numpy()
        on = np.bincount(objects[box], minlength=256).argmax() if box.any() else None
        steps.append(
            dict(
                target_px=int((objects == 1).sum()),
                on=None if on is None else int(on),
                presence=float(box_state.last_presence[0]),
            )
        )

    trajectory = run_episode(env, policy, seed, on_step=note)
    return first_index(trajectory.success), steps


def first_box_delay(steps: list[dict]) -> float:
    """Steps from the target's first view (>= SEEN_PX) to the first step with a box (NaN if either never
    comes): how long the exploration sweeps on past a target in view."""
    seen = first_index([s["target_px"] >= SEEN_PX for s in steps])
    boxed = first_index([s["on"] is not None for s in steps])
    return boxed - seen


def classify(steps: list[dict]) -> str:
    with_box = [s for s in steps if s["on"] is not None]
    on_target = sum(s["on"] == 1 for s in with_box)
    if sum(s["on"] not in (0, 1) for s in with_box) > on_target:
        return "on a look-alike"
    in_view = [s for s in steps if s["target_px"] >= SEEN_PX]
    if not in_view:
        return "target never in view"
    if sum(s["on"] is None for s in in_view) > len(in_view) / 2:
        return "target missed"
    return "on the target, not reached"


def class_lines(classes: dict[str, list[int]]) -> list[str]:
    """The report's count of lost episodes, then one line per class: how many, and their seeds (to record or
    replay one: `evaluate.py --seed S --episodes 1`)."""
    lines = [f"solved on the ground truth's box and not on the FCN's: {sum(map(len, classes.values()))}"]
    for kind in CLASSES:
        seeds = classes.get(kind, [])
        lines.append(f"  {kind}: {len(seeds)}" + (f" (seeds {', '.join(map(str, seeds))})" if seeds else ""))
    return lines


def main(args: Args):
    if args.env.box_source != "fcn":
        raise ValueError(f"--env.box-source is {args.env.box_source!r}: this compares the FCN's box (fcn)")
    fcn_env = make_env(args.env)
    truth_env = make_env(dataclasses.replace(args.env, box_source="ground_truth"))
    fcn_policy, truth_policy = make(fcn_env, args), make(truth_env, args)
    classes, relations, presences, successes = collections.defaultdict(list), collections.Counter(), [], [0, 0]
    both = []  # (steps to success, first-box delay) on the ground truth's box and on the FCN's, both solved
    for seed in tqdm(list(eval_seeds(args.episodes, args.seed)), desc="episodes"):
        truth_steps_to_success, truth_steps = box_steps(truth_env, truth_policy, seed)
        fcn_steps_to_success, steps = box_steps(fcn_env, fcn_policy, seed)
        truth_ok, fcn_ok = not np.isnan(truth_steps_to_success), not np.isnan(fcn_steps_to_success)
        if truth_ok and fcn_ok:
            both.append(
                (truth_steps_to_success, fcn_steps_to_success, first_box_delay(truth_steps), first_box_delay(steps))
            )
        successes[0] += truth_ok
        successes[1] += fcn_ok
        if not truth_ok or fcn_ok:
            continue
        kind = classify(steps)
        classes[kind].append(seed)
        if kind == "on a look-alike":
            base = fcn_env.unwrapped
            slot_kinds = slot_relations(base.object_names[0], base.object_colors[0])
            on = collections.Counter(s["on"] for s in steps if s["on"] not in (None, 0, 1)).most_common(1)[0][0]
            relations[RELATIONS[int(slot_kinds[on - 1])] if on <= len(slot_kinds) else "floor or robot"] += 1
            presences += [s["presence"] for s in steps if s["on"] == on]
    print(
        f"{'DQN ' + args.checkpoint if args.checkpoint else 'servo'} success on {args.episodes} episodes from {args.seed}: ground truth {successes[0] / args.episodes:.2f}, FCN {successes[1] / args.episodes:.2f}"
    )
    print("\n".join(class_lines(classes)))
    if relations:
        print(f"  look-alikes by relation: {dict(relations)}")
        print(
            f"  their boxes' presence score: median {np.median(presences):.2f}, 10th percentile {np.percentile(presences, 10):.2f}"
        )
    if both:
        truth_to_success, fcn_to_success, truth_delay, fcn_delay = np.array(both).T
        late = fcn_delay >= LATE_STEPS
        print(
            f"solved on both boxes: {len(both)}; steps to success {truth_to_success.mean():.1f} (ground truth) "
            f"against {fcn_to_success.mean():.1f} (FCN); from the target's first view to the first box "
            f"{np.nanmean(truth_delay):.1f} against {np.nanmean(fcn_delay):.1f} steps"
        )
        print(
            f"  first box {LATE_STEPS}+ steps after the target's first view (FCN): {int(late.sum())} episodes; "
            f"they take {(fcn_to_success - truth_to_success)[late].sum():.0f} more steps to success than on the ground "
            f"truth's box, all {len(both)} together {(fcn_to_success - truth_to_success).sum():.0f} more"
        )


if __name__ == "__main__":
    torch.set_num_threads(1)
    main(cli_with_checkpoint_env(Args))
