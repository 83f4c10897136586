"""How often the task's occluders hide the target from the search pose, and what the visibility rule costs.

For each scene (episode seeds from 1,000,000: held out), the camera is put at the search pose looking
straight at the target's azimuth (joint positions set, privileged) and the target's pixels are counted with
and without the panels: wholly hidden, partly hidden (visible fraction below the success threshold), in
view, or out of view even without panels. Then the scripted servo (ground-truth box) steps an env with and
without occluders in alternating blocks: milliseconds per step and the share of steps that render the
view a second time (the target borders a panel). The load is printed with the timings.

With `--rings`, for the scenes where a panel hides the target from the search pose: from which orbits could
a sweep see it? The camera is put (privileged, joint positions set) on rings of the lattice the directions
reach from the search pose (k forward steps, then j steps up or down), at azimuths within ±30° of the
target's in 3° steps, the camera end clear of the panels; a ring "sees" the target where some view shows at
least 20 of its pixels, and "sees it whole" where some such view has it fully in view (no border, no panel).

With `--split`, evaluations on these scenes are split the same way: do they find the targets a panel hides?

    .venv/bin/python baselines/occlusion.py --scenes 100 --occluders 2
    .venv/bin/python baselines/occlusion.py --scenes 50 --occluders 2 --rings --timing-steps 0
    .venv/bin/python baselines/occlusion.py --scenes 50 --image-size 128 --timing-steps 0 --split runs/over_eval/*.json
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from tqdm import tqdm

import mani_active_vision  # noqa: F401
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.envs import ENV_ID, EnvConfig, make_env
from mani_active_vision.evaluation.protocol import EVAL_SEED
from mani_active_vision.evaluation.views import view_stats
from mani_active_vision.occluders import MIN_VISIBLE_FRACTION, points_inside
from mani_active_vision.robots.iiwa import SEARCH_POS
from mani_active_vision.robots.orbit_controller import camera_end, solve_ik


@dataclass
class Args:
    scenes: int = 100
    """scenes (episode seeds from 1,000,000)"""
    occluders: int = 2
    object_set: str = "unseen"
    image_size: int = 64
    timing_steps: int = 300
    """servo steps per env for the cost of the visibility rule (0: skip)"""
    rings: bool = False
    """also: from which orbit rings the target hidden from the search pose could be seen"""
    ring_forward_steps: tuple[int, ...] = (0, 2, 4, 6, 8)
    ring_vertical_steps: tuple[int, ...] = (-6, -3, 0, 3)
    split: tuple[str, ...] = ()
    """evaluation JSONs (`evaluate.py --json`, `search_seeds.py`'s) on these scenes: their success on the scenes
    where a panel hides the target from the search pose and on those where it is in view"""


SEEN_PX = 20
"""target pixels that count as seen"""


def success_by_kind(episodes: list[dict], kinds: dict[int, str]) -> dict[str, tuple[float, int]]:
    """Success rate and episode count on the scenes where a panel hides the target from the search pose (wholly
    or partly) and on those where it is in view; an episode on a scene not classified is an error."""
    missing = sorted({e["seed"] for e in episodes} - kinds.keys())
    if missing:
        raise ValueError(
            f"episode seeds {missing[:3]}... are not among the {len(kinds)} scenes classified: raise --scenes"
        )
    out = {}
    for group, members in (("hidden", ("wholly_hidden", "partly_hidden")), ("in view", ("in_view",))):
        wins = [bool(e["success"]) for e in episodes if kinds[e["seed"]] in members]
        out[group] = (float(np.mean(wins)) if wins else math.nan, len(wins))
    return out


def search_view(base) -> tuple[int, int]:
    """(visible, unoccluded) target pixels with the camera at the search pose aimed at the target."""
    x, y = base.target.pose.p[0, :2].tolist()
    azimuth = math.atan2(y, x)
    pos = torch.tensor([[SEARCH_POS[0] * math.cos(azimuth), SEARCH_POS[0] * math.sin(azimuth), SEARCH_POS[2]]])
    qpos, _ = solve_ik(pos, base.agent.controller.config.pitch)
    base.agent.robot.set_qpos(qpos)
    base.forget_view()
    segmentation = base._hand_camera_images()["segmentation"][..., 0]
    visible = int((segmentation == base.target_seg_id[:, None, None]).sum())
    unoccluded = int(base._target_pixels_without_panels()[0]) if base.panels else visible
    return visible, unoccluded


def ring_pose(forward_steps: int, vertical_steps: int, step: float, pitch: float) -> tuple[float, float]:
    """(radius, height) of the camera k forward (along its pitched axis) and j vertical steps from the search pose."""
    radius = SEARCH_POS[0] + forward_steps * step * math.cos(pitch)
    return radius, SEARCH_POS[2] - forward_steps * step * math.sin(pitch) + vertical_steps * step


def ring_views(base, forward_steps: int, vertical_steps: int, pixels: int) -> tuple[bool, bool] | None:
    """(seen: some view shows >= SEEN_PX target pixels, whole: some such view has it fully in view) on the
    orbit ring k forward and j vertical steps from the search pose, at azimuths within ±30° of the target's
    (`pixels`: the wrist image's pixel count); None where no view on the ring is reachable (a height or
    radius off the controller's bounds, the camera end in a panel)."""
    config = base.agent.controller.config
    radius, height = ring_pose(forward_steps, vertical_steps, base.step_size, config.pitch)
    if not (config.min_height <= height <= config.max_height and config.min_radius <= radius <= config.max_radius):
        return None
    x, y = base.target.pose.p[0, :2].tolist()
    azimuths = math.atan2(y, x) + np.radians(np.arange(-30, 30.1, 3.0))
    points = torch.tensor([[radius * math.cos(a), radius * math.sin(a), height] for a in azimuths], dtype=torch.float32)
    qpos, ok = solve_ik(points, config.pitch)
    ok &= qpos[:, 3] <= config.max_elbow
    ok &= ~points_inside(camera_end(points, config.pitch), base.panel_layout().expand(len(points), -1, -1)).any(-1)
    if not ok.any():
        return None
    stats = view_stats(base, qpos[ok])
    seen = stats["target_fraction"] * pixels >= SEEN_PX  # the pixels no panel hides
    whole = seen & (stats["touches_border"] == 0)
    whole &= stats["target_visible_fraction"] >= MIN_VISIBLE_FRACTION
    return bool(seen.any()), bool(whole.any())


def step_costs(configs: dict[str, EnvConfig], steps: int, block: int = 50) -> dict[str, dict]:
    """ms per env step of the servo in each env, stepped in alternating blocks, and the share of steps that
    rendered the view twice."""
    envs = {name: make_env(c.replace(box_source="ground_truth")) for name, c in configs.items()}
    policies = {name: make_policy("servo", env) for name, env in envs.items()}
    times = {name: [] for name in envs}
    second = {name: 0 for name in envs}
    last = {}
    for name, env in envs.items():
        last[name] = env.reset(seed=EVAL_SEED)
        policies[name].reset(*last[name])
    for _ in tqdm(range(steps // block), desc="timing"):
        for name, env in envs.items():
            for _step in range(block):
                action = policies[name].act(*last[name])
                start = time.perf_counter()
                obs, _, _, truncated, info = env.step(action)
                times[name].append(time.perf_counter() - start)
                second[name] += env.unwrapped._unoccluded_pixels is not None
                last[name] = (obs, info)
                if bool(truncated):
                    last[name] = env.reset(seed=EVAL_SEED + len(times[name]))
                    policies[name].reset(*last[name])
    for env in envs.values():
        env.close()
    return {
        name: {
            "ms_median": 1000 * float(np.median(t)),
            "ms_mean": 1000 * float(np.mean(t)),
            "second_render_share": second[name] / len(t),
        }
        for name, t in times.items()
    }


def rule_costs(base, repeats: int = 200) -> dict[str, float]:
    """ms per call of the visibility rule's parts in the current view: the check that runs every step (the
    panels' layout for the controller, whether the target borders a panel) and the second render."""

    def per_call(f) -> float:
        start = time.perf_counter()
        for _ in range(repeats):
            f()
        return 1000 * (time.perf_counter() - start) / repeats

    segmentation = base._hand_camera_images()["segmentation"][..., 0]
    target = segmentation == base.target_seg_id[:, None, None]

    def second_render():
        base._unoccluded_pixels = None
        base._target_pixels_without_panels()

    return {
        "check every step": per_call(lambda: (base.panel_layout(), base._visible_fraction(segmentation, target))),
        "second render": per_call(second_render),
    }


def main(args: Args):
    torch.set_num_threads(1)
    config = EnvConfig(
        start_pose="search", object_set=args.object_set, image_size=args.image_size, occluders=args.occluders
    )
    env = gym.make(ENV_ID, **config.task_kwargs())
    base = env.unwrapped
    counts = dict(wholly_hidden=0, partly_hidden=0, in_view=0, out_of_view=0)
    kinds = {}
    for seed in tqdm(range(EVAL_SEED, EVAL_SEED + args.scenes), desc="scenes"):
        env.reset(seed=seed)
        visible, unoccluded = search_view(base)
        if unoccluded == 0:
            kinds[seed] = "out_of_view"
        elif visible == 0:
            kinds[seed] = "wholly_hidden"
        elif visible / unoccluded < MIN_VISIBLE_FRACTION:
            kinds[seed] = "partly_hidden"
        else:
            kinds[seed] = "in_view"
        counts[kinds[seed]] += 1
    hidden_seeds = [seed for seed, kind in kinds.items() if kind in ("wholly_hidden", "partly_hidden")]
    rings = {}
    if args.rings:
        for seed in tqdm(hidden_seeds, desc="rings"):
            env.reset(seed=seed)
            for k in args.ring_forward_steps:
                for j in args.ring_vertical_steps:
                    rings.setdefault((k, j), []).append(ring_views(base, k, j, args.image_size**2))
    costs = rule_costs(base)
    step, pitch = base.step_size, base.agent.controller.config.pitch
    env.close()
    print(
        f"\nThe target from the search pose aimed at it ({args.scenes} scenes, {args.object_set} objects, "
        f"{args.occluders} occluders, {args.image_size}²):\n"
    )
    print("| wholly hidden | partly hidden | in view | out of view without panels |")
    print("|---|---|---|---|")
    print("| " + " | ".join(f"{counts[k] / args.scenes:.2f}" for k in counts) + " |")
    if rings:
        print(
            f"\nThe {len(hidden_seeds)} scenes where a panel hides the target from the search pose, seen from orbit "
            "rings (k forward steps, then j up (+) or down (-); azimuths within ±30° of the target's):\n"
        )
        print("| ring (k, j) | radius, height (m) | rings reachable | target seen (≥ 20 px) | seen whole |")
        print("|---|---|---|---|---|")
        for (k, j), views in rings.items():
            reachable = [v for v in views if v is not None]
            radius, height = ring_pose(k, j, step, pitch)
            seen, whole = (sum(v[i] for v in reachable) / len(views) for i in (0, 1))
            print(
                f"| ({k}, {j:+d}) | {radius:.2f}, {height:.2f} | {len(reachable)}/{len(views)} | {seen:.2f} | "
                f"{whole:.2f} |"
            )
        seen_any = [
            any(rings[key][i] is not None and rings[key][i][0] for key in rings) for i in range(len(hidden_seeds))
        ]
        print(f"\nSeen from some ring: {np.mean(seen_any) if seen_any else 0:.2f} of the hidden scenes")
    if args.split:
        print("\nSuccess by what the search pose sees of the target:\n")
        print("| evaluation | hidden (wholly or partly) | in view |")
        print("|---|---|---|")
        for path in args.split:
            with open(path) as f:
                split = success_by_kind(json.load(f)["episodes"], kinds)
            print(f"| {path} | " + " | ".join(f"{rate:.2f} of {n}" for rate, n in split.values()) + " |")
    load = os.getloadavg()[0]
    print(
        f"\nThe visibility rule per call (load {load:.1f}): " + ", ".join(f"{k} {v:.2f} ms" for k, v in costs.items())
    )
    if args.timing_steps:
        load = os.getloadavg()[0]
        costs = step_costs(
            {"occluders=0": config.replace(occluders=0), f"occluders={args.occluders}": config}, args.timing_steps
        )
        print(
            f"\nRandom directions, {args.timing_steps} steps each, alternating blocks (load {load:.1f} -> "
            f"{os.getloadavg()[0]:.1f}):\n"
        )
        print("| env | ms per step (median) | (mean) | steps rendered twice |")
        print("|---|---|---|---|")
        for name, c in costs.items():
            print(f"| {name} | {c['ms_median']:.2f} | {c['ms_mean']:.2f} | {c['second_render_share']:.2f} |")


if __name__ == "__main__":
    main(tyro.cli(Args))
