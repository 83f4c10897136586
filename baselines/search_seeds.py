"""The memory agent (`agents.search`) over several training seeds, each evaluated with the project's protocol
(held-out seeds from 1,000,000, unseen objects, the FCN's box and the ground-truth box) beside the scripted
exploration + the shipped DQN, the scripted servo and the DQN without exploration on the same episodes; a
table per seed with mean ± std and the worst seed, the learning curves (success vs env steps) and the
camera's azimuth vs step beside the scripted sweep (docs/search.md).

    python baselines/search_seeds.py --seeds 0 1 2 3 4                 # DAgger from the shipped agent, 20,000 steps
    python baselines/search_seeds.py --train.algo ppo --train.teacher servo --total-steps 50000 --out-dir runs/search_ppo
    python baselines/search_seeds.py --report-only             # the table and figures from what is finished

Runs are kept under `out_dir/seed<k>` and skipped when finished (a run stopped by Ctrl-C is trained again);
each evaluation is cached in a JSON file, so a stopped run resumes where it was. The reference's steps
(for SPL) are measured once per box.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import tyro  # noqa: E402

from mani_active_vision.agents import search  # noqa: E402
from mani_active_vision.agents.policies import box_array, make_policy  # noqa: E402
from mani_active_vision.agents.q_network import checkpoint_env_config  # noqa: E402
from mani_active_vision.envs import EnvConfig, make_env  # noqa: E402
from mani_active_vision.evaluation.protocol import eval_seeds, evaluate, reference_table  # noqa: E402
from mani_active_vision.evaluation.report import spread  # noqa: E402
from mani_active_vision.evaluation.rollout import run_episode  # noqa: E402
from mani_active_vision.json_io import save_json  # noqa: E402
from mani_active_vision.metrics import summarize  # noqa: E402

COLUMNS = ("success", "success_final", "focus_held", "spl", "steps_to_see", "steps_to_success")
BOXES = ("fcn", "ground_truth")
WHERE = ("run_dir", "run_name")
"""`agents.search.Args` options that say where a run is written, not what it is"""


@dataclass
class Args:
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    """training seeds"""
    total_steps: int = 20_000
    """env steps per training run"""
    train: search.Args = field(default_factory=search.Args)
    """the learner's options (seed, total steps and folder are this script's)"""
    eval_episodes: int = 50
    """evaluation episodes per agent (seeds from 1,000,000, the same for every agent)"""
    eval_object_set: str = "unseen"
    """objects of the evaluation episodes"""
    boxes: list[str] = field(default_factory=lambda: list(BOXES))
    """the boxes the agents are evaluated on: fcn (as deployed) and ground_truth (the reference column)"""
    fcn_thresholds: tuple[float, float] = (0.0, 0.0)
    """the verifier's bars (acquire, track) of the memory agents' FCN box: 0 0 keeps their env's (the FCN's
    own); e.g. 0.97 0.9 (envs.DQN_FCN_THRESHOLDS) as the shipped DQN is deployed. Evaluations with bars are
    kept in their own files"""
    stay_needs_success: bool = False
    """the memory agents take `stay` only where the mask stats say success (`EnvConfig.stay_needs_success`, as
    `search_occluded.pt` is deployed; docs/task.md#occluders); their evaluations are kept in their own files"""
    held_box_tracking: bool = False
    """every policy on the FCN's box with the held box moving as the camera does and dropped once centred and unseen
    (`EnvConfig.with_held_box_tracking`, as `search_occluded.pt` is deployed; docs/task.md#occluders); these
    evaluations are kept in their own files"""
    dqn_checkpoint: str = "agents/weights/dqn_hold_demo_wide.pt"
    """the DQN of the baselines (explore -> dqn, and dqn without exploration): the teacher's"""
    out_dir: str = "runs/search_seeds"
    """where runs, evaluations and the table go"""
    figures_dir: str = "docs/figures"
    """where the learning curve and the azimuth plot go"""
    path_seed: int = 0
    """the training seed whose agent's camera path is plotted"""
    path_episodes: int = 4
    """evaluation episodes in the azimuth plot"""
    report_only: bool = False
    """only make the table and figures from finished runs and evaluations"""


def read_json(path: str):
    with open(path) as f:
        return json.load(f)


def cached(path: str, compute):
    """`compute()`, saved at `path`, or what was saved there."""
    if os.path.exists(path):
        return read_json(path)
    value = compute()
    save_json(value, path)
    return value


def seed_dir(args: Args, seed: int) -> str:
    return os.path.join(args.out_dir, f"seed{seed}")


def train_seed(args: Args, seed: int):
    """Train one seed, unless its folder holds a finished run with these options (one with others is an
    error: its evaluations would be taken for this configuration's; an option its run predates counts as its
    default; where the run was written from, `run_dir` and `run_name`, is no option: a run trained by
    `python -m mani_active_vision.agents.search --run-dir <out_dir>` into the same folder counts)."""
    history = os.path.join(seed_dir(args, seed), "history.json")
    options = dataclasses.replace(
        args.train, seed=seed, total_steps=args.total_steps, run_dir=args.out_dir, run_name=f"seed{seed}"
    )
    finished = read_json(history) if os.path.exists(history) else {"complete": False}
    if finished["complete"]:
        saved, wanted = finished["config"], json.loads(json.dumps(dataclasses.asdict(options)))
        defaults = json.loads(json.dumps(dataclasses.asdict(search.Args())))  # an option added since ran as its default
        differ = sorted(k for k in wanted if k not in WHERE and saved.get(k, defaults.get(k)) != wanted[k])
        if differ:
            raise ValueError(
                f"{seed_dir(args, seed)} holds a finished run with other options ({', '.join(differ)}): "
                "choose another --out-dir or remove that folder"
            )
        return
    search.train(options)


def eval_config(base: EnvConfig, args: Args, box: str, thresholds: tuple[float, float] | None = None) -> EnvConfig:
    """`base` on the evaluation objects, the training scenes' occluders (so that the baselines and the SPL's
    reference play the agents' scenes) and this box: the FCN's as deployed (`EnvConfig.on_fcn_box`, with
    `thresholds` the verifier's bars, with `held_box_tracking` the held box tracking the camera), or the ground
    truth's as it is (nothing held)."""
    base = base.replace(object_set=args.eval_object_set, occluders=args.train.env.occluders)
    if box != "fcn":
        return base.replace(box_source=box, box_hold_steps=0)
    base = base.on_fcn_box(thresholds)
    return base.with_held_box_tracking() if tracked(args, box) else base


def references(args: Args, box: str) -> dict[int, float]:
    """The privileged servo's steps per evaluation seed on this box as the memory agents see it, with their bars
    (cached; NaN where it fails, and then an agent's own steps are the shortest known), as `evaluate.py` runs it
    on the agent's env: the bars decide which sightings the servo gets, and so its steps."""
    thresholds = args.fcn_thresholds if barred(args, box) else None

    def compute():
        env = make_env(eval_config(EnvConfig(), args, box, thresholds))
        try:
            return reference_table(env, eval_seeds(args.eval_episodes))
        finally:
            env.close()

    name = f"reference_{box}{box_suffix(args, box)}_{args.eval_episodes}.json"
    value = cached(os.path.join(args.out_dir, name), compute)
    return {int(k): math.nan if v is None else v for k, v in value.items()}


def evaluate_cached(args: Args, path: str, config: EnvConfig, name: str, box: str, **kwargs) -> dict:
    """The summary and episodes of a policy on the evaluation episodes, cached at `path`."""

    def compute():
        env = make_env(config)
        try:
            policy = make_policy(name, env, **kwargs)
            episodes = evaluate(
                env, policy, eval_seeds(args.eval_episodes), references=references(args, box), desc=path
            )
        finally:
            env.close()
        return {"env": dataclasses.asdict(config), "summary": summarize(episodes), "episodes": episodes}

    return cached(path, compute)


def baselines(args: Args, box: str) -> dict[str, dict]:
    """The baselines' evaluations on this box: explore -> dqn (the teacher, with its sweep; and with the default
    sweep where the teacher's turns earlier), servo, dqn without exploration."""
    dqn_env = eval_config(checkpoint_env_config(args.dqn_checkpoint), args, box)
    suffix = f"{box}{box_suffix(args, box)}_{args.eval_episodes}.json"
    out = {}
    teacher = dict(then="dqn", checkpoint=args.dqn_checkpoint)
    runs = [("explore → dqn (the teacher)", "explore", "explore", teacher | sweep_kwargs(args))]
    if args.train.teacher_first_turn:  # the sweep as it turns by default, for steps to see
        runs.append(("explore → dqn, turning at joint 1's limit", "explore_at_limit", "explore", teacher))
    runs += [
        ("servo (scripted)", "servo", "servo", {}),
        ("dqn without exploration (the teacher's)", "dqn", "dqn", dict(checkpoint=args.dqn_checkpoint)),
    ]
    for label, key, name, kwargs in runs:
        path = os.path.join(args.out_dir, f"baseline_{key}_{suffix}")
        config = dqn_env if name != "servo" else eval_config(EnvConfig(), args, box)
        if args.report_only and not os.path.exists(path):
            continue
        out[label] = evaluate_cached(args, path, config, name, box, **kwargs)
    return out


def sweep_kwargs(args: Args) -> dict:
    """The teacher's sweep for an `explore` policy: where its orbit first turns back, if not at joint 1's limit."""
    return {"first_turn": args.train.teacher_first_turn} if args.train.teacher_first_turn else {}


def barred(args: Args, box: str) -> bool:
    return box == "fcn" and any(args.fcn_thresholds)


def tracked(args: Args, box: str) -> bool:
    return box == "fcn" and args.held_box_tracking


def box_suffix(args: Args, box: str) -> str:
    """Evaluations (and references) with the verifier's bars or the held box tracking are kept in their own files."""
    bars = "_bars{:g}_{:g}".format(*args.fcn_thresholds) if barred(args, box) else ""
    return bars + ("_tracking" if tracked(args, box) else "")


def memory_path(args: Args, seed: int, box: str) -> str:
    stay = "_stay_needs_success" if args.stay_needs_success else ""
    return os.path.join(seed_dir(args, seed), f"eval_{box}{box_suffix(args, box)}{stay}_{args.eval_episodes}.json")


def evaluate_seed(args: Args, seed: int, box: str) -> dict:
    checkpoint = os.path.join(seed_dir(args, seed), "agent.pt")
    thresholds = args.fcn_thresholds if barred(args, box) else None
    config = eval_config(checkpoint_env_config(checkpoint), args, box, thresholds)
    config = config.replace(stay_needs_success=config.stay_needs_success or args.stay_needs_success)
    return evaluate_cached(args, memory_path(args, seed, box), config, "memory", box, checkpoint=checkpoint)


def seen_share(episodes: list[dict]) -> float:
    """The share of episodes in which the target was ever in view (steps to see is the mean over those)."""
    return float(np.mean([e["steps_to_see"] is not None for e in episodes]))


def cells(result: dict) -> str:
    summary = result["summary"]
    return f"{seen_share(result['episodes']):.2f} | " + " | ".join(
        "–"
        if summary[k] is None or math.isnan(summary[k])
        else f"{summary[k]:.1f}"
        if k.startswith("steps")
        else f"{summary[k]:.2f}"
        for k in COLUMNS
    )


def table(args: Args, box: str) -> str:
    header = (
        "| agent | training s | env steps | saw the target | success | success at end | focus held | SPL "
        "| steps to see | steps to success |"
    )
    lines = [header, "|" + "---|" * 10]
    results = []
    for seed in args.seeds:
        path = memory_path(args, seed, box)
        if not os.path.exists(path):
            continue
        history = read_json(os.path.join(seed_dir(args, seed), "history.json"))
        result = read_json(path)
        results.append(result)
        lines.append(f"| memory seed {seed} | {history['seconds']:.0f} | {history['env_steps']} | {cells(result)} |")
    if results:
        summaries = [r["summary"] for r in results]
        means = " | ".join(spread([s[k] for s in summaries], 1 if k.startswith("steps") else 2) for k in COLUMNS)
        seen = spread([seen_share(r["episodes"]) for r in results])
        lines.append(f"| **memory: mean ± std over {len(results)} seeds** | | | {seen} | {means} |")
        worst = min(results, key=lambda r: r["summary"]["success"])
        lines.append(f"| memory: worst seed (by success) | | | {cells(worst)} |")
    for label, result in baselines(args, box).items():
        lines.append(f"| {label} | | | {cells(result)} |")
    return "\n".join(lines)


def plot_learning_curves(args: Args, path: str, bin_steps: int = 5_000):
    """Training success and success at the end (sampled actions) vs env steps, in bins of `bin_steps`:
    mean ± std over the seeds."""
    histories = [
        read_json(os.path.join(seed_dir(args, s), "history.json"))["history"]
        for s in args.seeds
        if os.path.exists(os.path.join(seed_dir(args, s), "history.json"))
    ]
    if not histories:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label in (("success", "success"), ("success_final", "success at the end")):
        last = min(max(h["env_step"] for h in history) for history in histories)
        edges = np.arange(0, last + 1, bin_steps)
        curves = []
        for history in histories:
            steps = np.array([h["env_step"] for h in history])
            values = np.array([h[key] for h in history])
            curves.append([values[(steps > a) & (steps <= a + bin_steps)].mean() for a in edges[:-1]])
        curves = np.array(curves)
        mean, std = curves.mean(0), curves.std(0)
        x = edges[1:]
        ax.plot(x, mean, label=f"{label} ({len(histories)} seeds)")
        ax.fill_between(x, mean - std, mean + std, alpha=0.25)
    demo_steps = read_json(os.path.join(seed_dir(args, args.seeds[0]), "history.json")).get("demo_env_steps", 0)
    if demo_steps:
        ax.axvline(demo_steps, color="grey", linestyle="--", linewidth=1)
        ax.text(demo_steps, 0.95, " PPO from here (before: the servo's episodes, cloned)", fontsize=7, color="grey")
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"training episodes' share ({bin_steps:,}-step bins)")
    learner = {"ppo": "recurrent PPO", "dagger": "DAgger"}[args.train.algo]
    box = {"fcn": "the FCN's box", "ground_truth": "ground-truth box"}[args.train.env.box_source]
    ax.set_title(f"memory agent ({learner}), {box}, train objects")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def camera_paths(config: EnvConfig, name: str, seeds, **kwargs) -> list[dict]:
    """The commanded azimuth (degrees) at every step of episodes of a policy, and its first success step."""
    env = make_env(config.replace(with_ee_pos=True))  # the commanded position comes with the box
    paths = []
    try:
        policy = make_policy(name, env, **kwargs)
        for seed in seeds:
            azimuth = []

            def log_azimuth(obs, info, azimuth=azimuth):
                x, y = box_array(obs)[0, 4:6]  # the commanded position follows the box
                azimuth.append(math.degrees(math.atan2(float(y), float(x))))

            trajectory = run_episode(env, policy, seed, on_step=log_azimuth)
            success = trajectory.success.index(True) if True in trajectory.success else None
            paths.append({"seed": seed, "azimuth": azimuth, "first_success": success})
    finally:
        env.close()
    return paths


def sweep_title(args: Args) -> str:
    turn = args.train.teacher_first_turn
    return f"scripted sweep (explore, first turn after {turn} steps)" if turn else "scripted sweep (explore)"


def plot_paths(args: Args, path: str):
    """Azimuth vs step of the memory agent (FCN box) and the scripted sweep on the same episodes."""
    checkpoint = os.path.join(seed_dir(args, args.path_seed), "agent.pt")
    if not os.path.exists(checkpoint):
        return
    seeds = list(eval_seeds(args.path_episodes))
    memory_env = eval_config(checkpoint_env_config(checkpoint), args, "fcn")
    runs = cached(
        os.path.join(args.out_dir, f"paths_seed{args.path_seed}_{args.path_episodes}.json"),
        lambda: {
            "memory": camera_paths(memory_env, "memory", seeds, checkpoint=checkpoint),
            "explore": camera_paths(eval_config(EnvConfig(), args, "fcn"), "explore", seeds, **sweep_kwargs(args)),
        },
    )
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, (key, title) in zip(
        axes, (("memory", f"memory agent (seed {args.path_seed}), FCN box"), ("explore", sweep_title(args)))
    ):
        for run in runs[key]:
            line = ax.plot(run["azimuth"], label=f"episode {run['seed']}")[0]
            if run["first_success"] is not None:
                s = run["first_success"]
                ax.plot(s, run["azimuth"][s], "o", color=line.get_color())
        ax.set_title(title)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("commanded azimuth (degrees)")
    axes[0].legend(fontsize=8)
    fig.suptitle("where the camera looks (the sweep is the same every episode): dots = first success", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args: Args):
    torch.set_num_threads(1)
    for box in args.boxes:
        if box not in BOXES:
            raise ValueError(f"box {box!r} is not one of: {', '.join(BOXES)}")
    if not args.report_only:
        for seed in args.seeds:
            train_seed(args, seed)
        for box in args.boxes:
            for seed in args.seeds:
                evaluate_seed(args, seed, box)
            baselines(args, box)
    os.makedirs(args.figures_dir, exist_ok=True)
    text = []
    for box in args.boxes:
        bars = " (memory agents with the verifier's bars {:g}, {:g})".format(*args.fcn_thresholds)
        tracking = ", the held box tracking the camera" if tracked(args, box) else ""
        text.append(f"### {box} box{bars if barred(args, box) else ''}{tracking}\n\n{table(args, box)}\n")
    note = (
        f"({args.eval_episodes} evaluation episodes per agent from seed 1,000,000, {args.eval_object_set} objects; "
        "saw the target: the share of episodes in which it was ever in view; focus held and steps over the episodes "
        "where they exist; memory agents greedy)\n"
    )
    with open(os.path.join(args.out_dir, "table.md"), "w") as f:
        f.write("\n".join(text) + "\n" + note)
    print("\n".join(text) + "\n" + note)
    plot_learning_curves(args, os.path.join(args.figures_dir, "search_learning_curve.png"), bin_steps=5_000)
    if not args.report_only or os.path.exists(
        os.path.join(args.out_dir, f"paths_seed{args.path_seed}_{args.path_episodes}.json")
    ):
        plot_paths(args, os.path.join(args.figures_dir, "search_azimuth.png"))


if __name__ == "__main__":
    main(tyro.cli(Args))
