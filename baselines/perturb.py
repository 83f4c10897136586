"""Perturbations: after the agent has focused on the target (first success), the arm is forced away for
a few steps in a random direction (small and large pushes), then the agent acts again. Reports the
recovery rate and the steps to recover, for a learned agent (the exploration handing over to a DQN, or the
memory agent) against the scripted servo.

    python baselines/perturb.py --checkpoint runs/fig5/random_explore/seed0/q_network.pt --episodes 10
    python baselines/perturb.py --policy memory --checkpoint agents/weights/search.pt --episodes 50 --push-steps 6
    python baselines/perturb.py --checkpoint runs/seeds/hold_stay_fine/seed1/q_network.pt --episodes 50 --no-servo

With a checkpoint the env is the one it was trained in (each `--env.*` flag given overrides that option);
its step limit is raised to fit focus, push and recovery.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from mani_active_vision.agents.policies import make_policy
from mani_active_vision.directions import DIRECTIONS
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.perturbation import perturbation_trial
from mani_active_vision.evaluation.protocol import EVAL_SEED
from mani_active_vision.json_io import save_json

FOCUS_LIMIT = 100
"""steps the agent gets to focus first"""


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env (default: the checkpoint's, if one is given)"""
    checkpoint: str = ""
    """the learned agent's checkpoint (empty: the servo only)"""
    policy: str = "explore"
    """what the checkpoint is: explore (a DQN trained with exploration, acting after it) or memory (the memory
    agent, agents/search.py: no script; its GRU is not shown the pushed steps)"""
    episodes: int = 10
    """scenes (seeds from `seed`); each gets one small and one large push"""
    seed: int = EVAL_SEED
    """first scene seed; also seeds the push directions"""
    push_steps: list[int] = field(default_factory=lambda: [2, 6])
    """forced steps per push: small and large (5 cm each)"""
    recover_limit: int = 50
    """steps the agent gets to focus again"""
    servo: bool = True
    """also push the scripted servo on the same scenes (--no-servo: the checkpoint only, e.g. when measuring
    several networks of one preset, whose servo rows would all be the same)"""
    json: str = "outputs/perturb.json"
    """where the results go"""


LEARNED = ("explore", "memory")


def main(args: Args):
    if args.policy not in LEARNED:
        raise ValueError(f"policy={args.policy!r} is not one of: {', '.join(LEARNED)}")
    if not (args.servo or args.checkpoint):
        raise ValueError("--no-servo needs a --checkpoint: there would be no policy to push")
    torch.set_num_threads(1)
    config = args.env.replace(max_episode_steps=FOCUS_LIMIT + max(args.push_steps) + args.recover_limit)
    env = make_env(config)
    policies = {"servo": make_policy("servo", env)} if args.servo else {}
    if args.checkpoint and args.policy == "memory":
        policies["memory"] = make_policy("memory", env, checkpoint=args.checkpoint)
    elif args.checkpoint:
        policies["explore→dqn"] = make_policy("explore", env, then="dqn", checkpoint=args.checkpoint, seed=args.seed)
    rng = np.random.default_rng(args.seed)
    pushes = rng.integers(0, len(DIRECTIONS), size=(args.episodes, len(args.push_steps)))
    results = {}
    rows = [
        "| policy | push | focused | recovered (of focused) | steps to recover | target still in view after push |",
        "|---|---|---|---|---|---|",
    ]
    try:
        for name, policy in policies.items():
            for j, steps in enumerate(args.push_steps):
                trials = [
                    perturbation_trial(
                        env, policy, args.seed + i, int(pushes[i, j]), steps, FOCUS_LIMIT, args.recover_limit
                    )
                    for i in tqdm(range(args.episodes), desc=f"{name} push {steps}", leave=False)
                ]
                focused = [t for t in trials if t["focused"]]
                recovered = [t for t in focused if t["recovered"]]
                rate = len(recovered) / len(focused) if focused else float("nan")
                steps_to_recover = [t["steps_to_recover"] for t in recovered]
                steps_mean = np.mean(steps_to_recover) if recovered else float("nan")
                steps_std = np.std(steps_to_recover) if recovered else float("nan")
                visible = np.mean([t["visible_after_push"] for t in focused]) if focused else float("nan")
                results[f"{name}/push{steps}"] = {
                    "trials": trials,
                    "pushes": [DIRECTIONS[int(d)] for d in pushes[:, j]],
                    "recovery_rate": rate,
                    "steps_to_recover": steps_mean,
                }
                rows.append(
                    f"| {name} | {steps} × {config.step_size * 100:.0f} cm | {len(focused)}/{len(trials)} | {rate:.2f} | "
                    f"{steps_mean:.1f} ± {steps_std:.1f} | {visible:.2f} |"
                )
    finally:
        env.close()
    print("\n".join(rows))
    save_json(
        {"env": dataclasses.asdict(config), "checkpoint": args.checkpoint, "table": rows, "results": results}, args.json
    )
    print(f"results written to {args.json}")


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
