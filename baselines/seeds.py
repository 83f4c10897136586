"""One DQN preset over several training seeds: each seed trains (scripted exploration, then the DQN) and its
greedy agent is evaluated on the same held-out episodes; a table per seed, mean ± std over seeds and the
worst seed, beside the scripted servo on the same episodes.

    python baselines/seeds.py --preset hold --seeds 0 1 2 3 4 --eval-episodes 50 --eval-object-set unseen
    python baselines/seeds.py --preset hold_demo --set demo_episodes=20 demo_margin=0.8 --name hold_demo20_margin

`--set` changes options of the preset (an option tried, not yet a preset), `--name` names its runs.
Runs are kept under `out_dir/name/seed<k>` and skipped when finished, so one seed at a time can be run
(`--seeds 3`) and the table made from all finished ones (`--report-only`); a finished training is only
evaluated, so `--eval-box-source fcn` evaluates the same agents on the FCN's box (eval_fcn.json beside eval.json);
an evaluation taken in another env (other `--env.*` flags) is an error, not reused. The reference's steps (for SPL)
and the servo's evaluation are measured once per evaluation env and episode count, and cached.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np
import torch

from mani_active_vision.agents import dqn
from mani_active_vision.agents.policies import make_policy
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_preset_env
from mani_active_vision.evaluation.protocol import eval_seeds, evaluate, reference_table
from mani_active_vision.evaluation.report import spread
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import summarize

COLUMNS = ("success", "success_final", "focus_held", "spl", "steps_to_success")


@dataclass
class Args:
    preset: str = "hold"
    """the DQN preset (agents.dqn.PRESETS: paper, shaped, hold, ...)"""
    set: list[str] = field(default_factory=list)
    """options of agents.dqn.Args changed from the preset's, as name=value (a JSON value: 20, 0.8, true)"""
    name: str = ""
    """the runs' folder and label (default: the preset's name)"""
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    """training seeds"""
    episodes: int = 100
    """training episodes per seed"""
    eval_episodes: int = 50
    """greedy evaluation episodes per seed (seeds from 1,000,000, the same for every training seed)"""
    eval_object_set: str = "unseen"
    """objects of the evaluation episodes (training uses env.object_set)"""
    eval_box_source: str = "ground_truth"
    """the box the agent acts on when evaluated: ground_truth or fcn"""
    eval_fine_step_size: float | None = None
    """the evaluation env's fine moves (EnvConfig.fine_step_size; 0: none; None: the training env's, e.g. the
    shipped preset's envs.DQN_FINE_STEP_SIZE): the DQN (trained with them or on the full step) and the servo take
    them near the target, as the shipped DQN is deployed"""
    env: EnvConfig = field(default_factory=EnvConfig)
    """the training env (ground-truth box, train objects by default)"""
    out_dir: str = "runs/seeds"
    """where runs, caches and the table go"""
    report_only: bool = False
    """only make the table from finished runs"""


def read_json(path: str):
    with open(path) as f:
        return json.load(f)


def cached(path: str, key: dict, compute):
    """`compute()`, saved at `path` with `key`, or the saved value when `key` matches."""
    if os.path.exists(path):
        saved = read_json(path)
        if saved["key"] == key:
            return saved["value"]
    value = compute()
    save_json({"key": key, "value": value}, path)
    return value


def label(args: Args) -> str:
    return args.name or args.preset


def train_options(args: Args) -> dict:
    """`--set`'s name=value pairs, checked against agents.dqn.Args (the run's env, seed, episodes and folder
    are this script's)."""
    fields = {f.name for f in dataclasses.fields(dqn.Args)} - {"env", "seed", "episodes", "run_dir", "run_name"}
    options = {}
    for item in args.set:
        key, _, value = item.partition("=")
        if key not in fields:
            raise ValueError(f"--set {item!r}: {key!r} is not one of: {', '.join(sorted(fields))}")
        options[key] = json.loads(value)
    return options


def eval_env_config(args: Args) -> EnvConfig:
    return args.env.replace(
        object_set=args.eval_object_set, box_source=args.eval_box_source, fine_step_size=eval_fine_step_size(args)
    )


def eval_fine_step_size(args: Args) -> float:
    """The evaluation's fine step: `eval_fine_step_size`, or where it is None the training env's."""
    return args.env.fine_step_size if args.eval_fine_step_size is None else args.eval_fine_step_size


def eval_suffix(args: Args) -> str:
    """What names an evaluation's files besides the objects: "" on the ground-truth box, "_<box>" on another,
    then "_fine" with the fine moves."""
    box = "" if args.eval_box_source == "ground_truth" else f"_{args.eval_box_source}"
    return box + fine(args)


def fine(args: Args) -> str:
    """The suffix "_fine" where the evaluation has the fine moves, else ""."""
    return "_fine" if eval_fine_step_size(args) else ""


def references(args: Args) -> dict[int, float]:
    """The reference's steps per evaluation seed (cached; NaN where it fails)."""
    config = eval_env_config(args)
    key = {"env": dataclasses.asdict(config), "episodes": args.eval_episodes}

    def compute():
        env = make_env(config)
        try:
            return reference_table(env, eval_seeds(args.eval_episodes))
        finally:
            env.close()

    value = cached(
        os.path.join(args.out_dir, f"reference_{args.eval_object_set}_{args.eval_box_source}{fine(args)}.json"),
        key,
        compute,
    )
    return {int(k): math.nan if v is None else v for k, v in value.items()}


def evaluate_policy(args: Args, name: str, **kwargs) -> dict:
    """The summary of a policy on the evaluation episodes (explore → dqn when given a checkpoint)."""
    env = make_env(eval_env_config(args))
    try:
        policy = make_policy(name, env, **kwargs)
        episodes = evaluate(env, policy, eval_seeds(args.eval_episodes), references=references(args), desc=name)
    finally:
        env.close()
    return {"summary": summarize(episodes), "episodes": episodes}


def eval_path(args: Args, seed_dir: str) -> str:
    """A seed's evaluation: eval.json on the ground-truth box, eval_<box>.json on another (`eval_suffix`)."""
    return os.path.join(seed_dir, f"eval{eval_suffix(args)}.json")


def saved_evaluation(args: Args, path: str) -> dict | None:
    """A seed's finished evaluation at `path`, None if there is none. One taken in another env (e.g. the FCN
    segmenting at another size) is a ValueError naming what differs, not reused; one saved before an option
    existed counts as taken at its default."""
    if not os.path.exists(path):
        return None
    saved = read_json(path)
    if "eval_env" not in saved:  # written before evaluations kept their env: nothing to check it against
        return saved
    taken = dataclasses.asdict(EnvConfig.from_dict(saved["eval_env"]))
    wanted = dataclasses.asdict(eval_env_config(args))
    differ = [f"{key}: {taken[key]!r} != {wanted[key]!r}" for key in wanted if taken[key] != wanted[key]]
    if differ:
        raise ValueError(
            f"{path} holds an evaluation in another env ({', '.join(differ)}): choose another --out-dir or remove it"
        )
    return saved


def servo_path(args: Args) -> str:
    return os.path.join(args.out_dir, f"servo_{args.eval_object_set}_{args.eval_box_source}{fine(args)}.json")


def run_seed(args: Args, seed: int):
    """Train the seed unless its training finished, then evaluate it unless already evaluated on this box."""
    run_dir = os.path.join(args.out_dir, label(args))
    path = eval_path(args, os.path.join(run_dir, f"seed{seed}"))
    if saved_evaluation(args, path) is not None:
        return
    history = os.path.join(run_dir, f"seed{seed}", "history.json")
    if os.path.exists(history) and read_json(history)["complete"]:
        checkpoint = os.path.join(run_dir, f"seed{seed}", "q_network.pt")
        result = evaluate_policy(args, "explore", then="dqn", checkpoint=checkpoint, seed=seed)
        save_json({"eval_env": dataclasses.asdict(eval_env_config(args)), **result}, path)
        return
    train_args = dataclasses.replace(
        dqn.PRESETS[args.preset][1],
        **train_options(args),
        env=args.env,
        seed=seed,
        episodes=args.episodes,
        explore=True,
        run_dir=run_dir,
        run_name=f"seed{seed}",
    )
    dqn.train(train_args)
    run_seed(args, seed)


def report(args: Args) -> str:
    run_dir = os.path.join(args.out_dir, label(args))
    rows, summaries = [], []
    header = (
        "| run | training s | training success, last 10 | success | success at end | focus held | SPL "
        "| steps to success |"
    )
    for seed_dir in sorted(os.listdir(run_dir)) if os.path.isdir(run_dir) else []:
        path = os.path.join(run_dir, seed_dir)
        saved = saved_evaluation(args, eval_path(args, path))
        if saved is None:
            continue
        history = read_json(os.path.join(path, "history.json"))
        summary = saved["summary"]
        summaries.append(summary)
        last10 = np.mean([h["success"] for h in history["history"][-10:]])
        rows.append(f"| {label(args)} {seed_dir} | {history['seconds']:.0f} | {last10:.2f} | " + cells(summary) + " |")
    lines = [header, "|" + "---|" * 8, *rows]
    if summaries:
        means = {k: spread([s[k] for s in summaries]) for k in COLUMNS}
        lines.append(
            f"| **{label(args)}: mean ± std over {len(summaries)} seeds** | | | " + " | ".join(means.values()) + " |"
        )
        worst = min(summaries, key=lambda s: s["success"])
        lines.append(f"| {label(args)}: worst seed (by success) | | | " + cells(worst) + " |")
    servo = servo_path(args)
    if os.path.exists(servo):
        lines.append("| servo (scripted) | | | " + cells(read_json(servo)["value"]["summary"]) + " |")
    table = "\n".join(lines)
    note = (
        f"\n\n({args.eval_episodes} evaluation episodes per seed from 1,000,000, {args.eval_object_set} objects, "
        f"{args.eval_box_source} box{', fine moves near the target' if eval_fine_step_size(args) else ''}; focus held "
        "over the successful episodes; in the mean row, focus held and steps to success are over the seeds where "
        "they exist)\n"
    )
    with open(os.path.join(args.out_dir, f"{label(args)}{eval_suffix(args)}_table.md"), "w") as f:
        f.write(table + note)
    return table


def cells(summary: dict) -> str:
    values = [summary[k] for k in COLUMNS]
    return " | ".join(
        "–" if v is None or math.isnan(v) else f"{v:.2f}" if k != "steps_to_success" else f"{v:.1f}"
        for k, v in zip(COLUMNS, values)
    )


def main(args: Args):
    torch.set_num_threads(1)
    if args.preset not in dqn.PRESETS:
        raise ValueError(f"preset={args.preset!r} is not one of: {', '.join(dqn.PRESETS)}")
    train_options(args)  # a wrong --set fails before anything runs
    if not args.report_only:
        key = {"env": dataclasses.asdict(eval_env_config(args)), "episodes": args.eval_episodes}
        cached(servo_path(args), key, lambda: evaluate_policy(args, "servo"))
        for seed in args.seeds:
            run_seed(args, seed)
    print(report(args))


if __name__ == "__main__":
    main(cli_with_preset_env(Args))
