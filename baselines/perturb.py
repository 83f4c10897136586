"""Perturbations: after the agent has focused on the target (first success), the arm is forced away for
a few steps in a random direction (small and large pushes), then the agent acts again. Reports the
recovery rate and the steps to recover, for the DQN (exploration, then DQN) against the scripted servo.

    python baselines/perturb.py --checkpoint runs/fig5/random_explore/seed0/q_network.pt --episodes 10
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import torch
import tyro
from tqdm import tqdm

from mani_active_vision.agents.dqn import env_kwargs, load_q_network, Args as DQNArgs
from mani_active_vision.agents.evaluation import make_box_env, perturbation_trial, save_json
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.directions import DIRECTIONS


@dataclass
class Args:
    checkpoint: str = ""
    """a DQN checkpoint trained with exploration (empty: the servo only)"""
    episodes: int = 10
    """scenes (seeds from `seed`); each gets one small and one large push"""
    seed: int = 1_000_000
    """first scene seed; also seeds the push directions"""
    push_steps: list[int] = field(default_factory=lambda: [2, 6])
    """forced steps per push: small and large (5 cm each)"""
    recover_limit: int = 50
    """steps the agent gets to focus again"""
    json: str = "outputs/perturb.json"
    """where the results go"""


def main(args: Args):
    torch.set_num_threads(1)
    options = env_kwargs(DQNArgs(**{k: v for k, v in load_q_network(args.checkpoint)[1].items() if k in DQNArgs.__dataclass_fields__})) if args.checkpoint else env_kwargs(DQNArgs())
    env = make_box_env(**options, max_episode_steps=100 + max(args.push_steps) + args.recover_limit)
    policies = {"servo": make_policy("servo", env)}
    if args.checkpoint:
        policies["explore→dqn"] = make_policy("explore", env, then="dqn", checkpoint=args.checkpoint, seed=args.seed)
    rng = np.random.default_rng(args.seed)
    pushes = rng.integers(0, len(DIRECTIONS), size=(args.episodes, len(args.push_steps)))
    results, rows = {}, ["| policy | push | focused | recovered (of focused) | steps to recover | target still in view after push |", "|---|---|---|---|---|---|"]
    for name, policy in policies.items():
        for j, steps in enumerate(args.push_steps):
            trials = [perturbation_trial(env, policy, args.seed + i, int(pushes[i, j]), steps, recover_limit=args.recover_limit)
                      for i in tqdm(range(args.episodes), desc=f"{name} push {steps}", leave=False)]
            focused = [t for t in trials if t["focused"]]
            recovered = [t for t in focused if t["recovered"]]
            rate = len(recovered) / len(focused) if focused else float("nan")
            steps_mean = np.mean([t["steps_to_recover"] for t in recovered]) if recovered else float("nan")
            steps_std = np.std([t["steps_to_recover"] for t in recovered]) if recovered else float("nan")
            visible = np.mean([t["visible_after_push"] for t in focused]) if focused else float("nan")
            results[f"{name}/push{steps}"] = {"trials": trials, "pushes": [DIRECTIONS[int(d)] for d in pushes[:, j]],
                                              "recovery_rate": rate, "steps_to_recover": steps_mean}
            rows.append(f"| {name} | {steps} × {env.unwrapped.step_size * 100:.0f} cm | {len(focused)}/{len(trials)} | {rate:.2f} | "
                        f"{steps_mean:.1f} ± {steps_std:.1f} | {visible:.2f} |")
    env.close()
    print("\n".join(rows))
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    save_json({"env": options, "checkpoint": args.checkpoint, "table": rows, "results": results}, args.json)
    print(f"results written to {args.json}")


if __name__ == "__main__":
    main(tyro.cli(Args))
