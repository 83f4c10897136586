"""Can success be *kept* with the six directions? The ceiling of holding focus, privileged.

For each random placement (seed) the camera is put at every lattice pose near the target that the
success ceiling uses (`baselines/success_reachability.py`: joint positions set directly, no stepping) and
the views in success are found. From each of them the six steps are judged as the controller judges them
(`step_allowed`), and the views one accepted step away are rendered. A placement can hold success
- by oscillating: some view in success has a neighbour one step away in success (the step and the step
  back are exact inverses, so alternating them stays in success at every step);
- by a refused step: from some view in success a direction is refused, so the arm does not move;
- with the optional `stay` action: whenever some view succeeds at all (the reach ceiling).
Each oscillation found (the pair with the most successful neighbours) and each refusal hold is then
checked in the simulator: the arm is set there and the env stepped (physics, the real controller) for
`--verify-steps` steps; "verified" = success at every one of them.

    .venv/bin/python baselines/hold_ceiling.py --placements 40 --resolution 128
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
import tyro
from tqdm import tqdm

import mani_active_vision  # noqa: F401
from mani_active_vision.directions import DIRECTIONS, DiscreteDirections
from mani_active_vision.envs import ENV_ID, EnvConfig
from mani_active_vision.evaluation.views import REVERSE, candidate_positions, meets, neighbours, view_stats
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import first_env
from mani_active_vision.robots.orbit_controller import solve_ik


@dataclass
class Args:
    placements: int = 40
    """number of random placements (seeds 0..placements-1)"""
    resolution: int = 128
    """wrist camera width = height"""
    object_set: str = "train"
    """train, unseen or primitives"""
    verify_steps: int = 10
    """simulator check: steps of oscillation (or of the refused direction) that must all be in success"""
    json: str = ""
    """where the per-placement results go (default: outputs/hold_ceiling_<resolution>.json)"""


def hold_in_simulator(env, qpos: torch.Tensor, actions: list[int]) -> bool:
    """Set the arm of env 0 to `qpos` (7,) as a controller start, take `actions`; success at every step?"""
    base = env.unwrapped
    base.agent.robot.set_qpos(qpos[None])
    base.agent.robot.set_qvel(torch.zeros(1, 7))
    base.agent.controller.start_episode(torch.arange(1), qpos[None])
    kept = True
    for action in actions:
        _, _, _, _, info = env.step(np.int64(action))
        kept &= bool(first_env(info, "success"))
    return kept


def placement(env, seed: int, config: EnvConfig, verify_steps: int) -> dict:
    """What holding a placement allows (see the module docstring)."""
    env.reset(seed=seed)
    base = env.unwrapped
    arm = base.agent.controller.config
    target_xy = base.target.pose.p[0, :2].numpy()
    points = torch.as_tensor(
        candidate_positions(target_xy, base.step_size, arm.pitch, arm.min_height), dtype=torch.float32
    )
    qpos, ok = solve_ik(points, arm.pitch)
    ok &= qpos[:, 3] <= arm.max_elbow
    points, qpos = points[ok], qpos[ok]
    success = meets(view_stats(base, qpos), config.success_fraction, config.success_center_tol)
    found, found_q = points[success], qpos[success]
    _, next_q, allowed = neighbours(found, found_q, base.step_size, arm)
    next_success = np.zeros(tuple(allowed.shape), dtype=bool)
    if allowed.any():
        stats = view_stats(base, next_q[allowed])
        next_success[allowed.numpy()] = meets(stats, config.success_fraction, config.success_center_tol)
    result = {
        "seed": seed,
        "views": int(len(points)),
        "views_in_success": int(len(found)),
        "views_holdable_by_oscillation": int(next_success.any(1).sum()),
        "reach": bool(len(found)),
        "oscillation": bool(next_success.any()),
        "refusal": bool((~allowed).any()),
        "oscillation_verified": None,
        "refusal_verified": None,
    }
    if result["oscillation"]:
        i = int(next_success.sum(1).argmax())
        d = int(next_success[i].argmax())
        back = DIRECTIONS.index(REVERSE[DIRECTIONS[d]])
        result["oscillation_pair"] = [found[i].tolist(), DIRECTIONS[d]]
        result["oscillation_verified"] = hold_in_simulator(env, found_q[i], [d, back] * (verify_steps // 2))
    if result["refusal"]:
        i, d = (int(v) for v in torch.nonzero(~allowed)[0])
        result["refusal_pose"] = [found[i].tolist(), DIRECTIONS[d]]
        result["refusal_verified"] = hold_in_simulator(env, found_q[i], [d] * verify_steps)
    return result


def share(results: list[dict], key: str) -> float:
    return float(np.mean([bool(r[key]) for r in results]))


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    config = EnvConfig(
        start_pose="search", object_set=args.object_set, image_size=args.resolution, max_episode_steps=10_000
    )
    env = DiscreteDirections(gym.make(ENV_ID, **config.task_kwargs()))
    try:
        results = [
            placement(env, seed, config, args.verify_steps) for seed in tqdm(range(args.placements), desc="placements")
        ]
    finally:
        env.close()
    for r in results:
        r["either"] = r["oscillation"] or r["refusal"]
        r["either_verified"] = bool(r["oscillation_verified"]) or bool(r["refusal_verified"])
    summary = {
        k: share(results, k)
        for k in ("reach", "oscillation", "oscillation_verified", "refusal", "refusal_verified", "either")
    }
    summary["either_verified"] = share(results, "either_verified")
    print(
        f"\nShare of {args.placements} random placements ({args.object_set} objects, {args.resolution}², success "
        f"{config.success_fraction} / {config.success_center_tol}) where success can be held:\n"
    )
    print(
        "| resolution | placements | reach (= hold with stay) | oscillating between two adjacent views "
        "(verified) | a refused step (verified) | either (verified) |"
    )
    print("|---|---|---|---|---|---|")
    print(
        f"| {args.resolution}² | {args.placements} | {summary['reach']:.2f} | {summary['oscillation']:.2f} "
        f"({summary['oscillation_verified']:.2f}) | {summary['refusal']:.2f} ({summary['refusal_verified']:.2f}) | "
        f"{summary['either']:.2f} ({summary['either_verified']:.2f}) |"
    )
    path = args.json or f"outputs/hold_ceiling_{args.resolution}.json"
    save_json({"args": dataclasses.asdict(args), "summary": summary, "placements": results}, path)
    print(f"results written to {path}")
    return summary


if __name__ == "__main__":
    main(tyro.cli(Args))
