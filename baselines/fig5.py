"""The paper's Fig. 5: DQN learning curves over several seeds, mean ± spread, and a table.

(a) fixed object placement; (b) random placement with and without the scripted exploration;
(c) random placement with exploration, with and without the link state (camera position) in the state.

    python baselines/fig5.py                                        # every run, as Ray tasks: one per core
    python baselines/fig5.py --ray-address auto                     # on the Ray cluster this machine joined
    python baselines/fig5.py --conditions fixed --seeds 0 1 2 --sequential   # one after another, no Ray
    python baselines/fig5.py --plot-only                            # curves and table from finished runs

Each (condition, seed) trains `agents.dqn` (paper configuration) and then evaluates the greedy agent on
fixed evaluation seeds (`evaluation.training_run`); the runs are a `sweep` (docs/distributed.md): finished
runs are skipped, so an interrupted job resumes, and the results are the same however the runs were spread.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np
import torch
import tyro

from mani_active_vision.agents import dqn
from mani_active_vision.envs import EnvConfig
from mani_active_vision.evaluation.report import plot_curves, spread
from mani_active_vision.evaluation.training_run import train_and_evaluate
from mani_active_vision.sweep import Run, run_sweep

CONDITIONS = {  # name: (env options, DQN options)
    "fixed": (dict(placement="fixed"), dict(explore=False)),
    "random_explore": (dict(placement="random"), dict(explore=True)),
    "random_noexplore": (dict(placement="random"), dict(explore=False)),
    "random_explore_link": (dict(placement="random", with_ee_pos=True), dict(explore=True)),
    # not in the paper: the reward capped at the success fraction (normalized_dense), so that zooming past
    # the success fraction (until the target touches the border) earns nothing more
    "random_explore_capped_reward": (dict(placement="random", reward_mode="normalized_dense"), dict(explore=True)),
    # not in the paper: the `shaped` preset of agents/dqn.py (see its docstring: episode end and bonus at
    # success, potential shaping on the target fraction and centring, step and refusal costs, γ 0.99,
    # 5-step returns, the last direction in the state, double DQN, mirrored transitions, 2 updates per step)
    "random_explore_shaped": (dict(placement="random"), dict(explore=True, **dqn.SHAPED)),
    "fixed_shaped": (dict(placement="fixed"), dict(explore=False, **dqn.SHAPED)),
}
FIGURES = {
    "a_fixed": ["fixed"],
    "b_exploration": ["random_explore", "random_noexplore"],
    "c_link_state": ["random_explore", "random_explore_link"],
    "d_capped_reward": ["random_explore", "random_explore_capped_reward"],
    "e_shaped": ["random_explore", "random_explore_shaped"],
    "f_fixed_shaped": ["fixed", "fixed_shaped"],
}


@dataclass
class Args:
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))
    """which conditions to run (see CONDITIONS)"""
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    """training seeds per condition"""
    episodes: int = 100
    """training episodes per run (paper: 100)"""
    eval_episodes: int = 20
    """greedy evaluation episodes per run (seeds from 1,000,000)"""
    out_dir: str = "runs/fig5"
    """where runs, curves and the table go"""
    plot_only: bool = False
    """only collect finished runs into curves and the table"""
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env options every condition starts from (each condition sets its own on top)"""
    ray_address: str | None = None
    """the Ray cluster to run on: auto (the one this machine joined with `ray start`), host:6379 or
    ray://host:10001; unset: a local Ray, one run per core"""
    sequential: bool = False
    """run one after another in this process, without Ray"""


def runs(args: Args) -> list[Run]:
    """One run per (condition, seed) of `args`, in the folder `out_dir/<condition>/seed<seed>`."""
    found = []
    for condition in args.conditions:
        env_options, dqn_options = CONDITIONS[condition]
        for seed in args.seeds:
            train_args = dqn.Args(env=args.env.replace(**env_options), seed=seed, episodes=args.episodes, **dqn_options)
            found.append(
                Run(f"{condition}/seed{seed}", train_and_evaluate, (train_args, args.eval_episodes, args.sequential))
            )
    return found


def read_json(path: str):
    with open(path) as f:
        return json.load(f)


def collect(args: Args) -> dict:
    """condition -> {"histories": [per-seed list of episode dicts], "evals": [per-seed summary]}."""
    found = {}
    for condition in CONDITIONS:
        histories, evals = [], []
        for seed_dir in (
            sorted(os.listdir(os.path.join(args.out_dir, condition)))
            if os.path.isdir(os.path.join(args.out_dir, condition))
            else []
        ):
            path = os.path.join(args.out_dir, condition, seed_dir)
            if os.path.exists(os.path.join(path, "eval.json")):
                histories.append(read_json(os.path.join(path, "history.json"))["history"])
                evals.append(read_json(os.path.join(path, "eval.json"))["summary"])
        if histories:
            found[condition] = {"histories": histories, "evals": evals}
    return found


def report(args: Args):
    found = collect(args)
    for figure, conditions in FIGURES.items():
        present = [c for c in conditions if c in found]
        for key, label in (("return", "episode return"), ("success", "success rate")):
            if present:
                path = os.path.join(args.out_dir, f"fig5{figure}_{key}.png")
                plot_curves(
                    {c: [[h[key] for h in hist] for hist in found[c]["histories"]] for c in present},
                    path,
                    label,
                    title=f"Fig. 5 {figure}",
                )
                print(f"wrote {path}")
    lines = [
        "| condition | seeds | training success, last 10 episodes | training return, last 10 | eval success (greedy) | eval success at end | eval focus held | eval steps to success | eval final target fraction |",
        "|" + "---|" * 9,
    ]
    for condition, data in found.items():
        last = [np.mean([h["success"] for h in hist[-10:]]) for hist in data["histories"]]
        last_return = [np.mean([h["return"] for h in hist[-10:]]) for hist in data["histories"]]
        ev = data["evals"]
        lines.append(
            f"| {condition} | {len(ev)} | {spread(last)} | {spread(last_return)} | {spread([e['success'] for e in ev])} | "
            f"{spread([e['success_final'] for e in ev])} | {spread([e.get('focus_held') for e in ev])} | {spread([e['steps_to_success'] for e in ev])} | {spread([e['final_target_fraction'] for e in ev], 3)} |"
        )
    table = "\n".join(lines)
    with open(os.path.join(args.out_dir, "fig5_table.md"), "w") as f:
        f.write(table + "\n\n(mean ± std over seeds; eval: greedy policy, episodes from seed 1,000,000)\n")
    print(table)


def main(args: Args):
    torch.set_num_threads(1)
    for condition in args.conditions:
        if condition not in CONDITIONS:
            raise ValueError(f"condition={condition!r} is not one of: {', '.join(CONDITIONS)}")
    if not args.plot_only:
        run_sweep(runs(args), args.out_dir, address=args.ray_address, sequential=args.sequential)
    report(args)


if __name__ == "__main__":
    main(tyro.cli(Args))
