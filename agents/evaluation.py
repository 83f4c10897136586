"""Rolling out policies on the box-state env and scoring episodes (DESIGN §6): one place builds the env,
one place turns a trajectory into metrics, one place draws learning curves.

Metrics of one episode (`episode_metrics`), steps counted in actions taken:
- `success`: the task's success held at some step; `success_final`: it holds at the last step (kept focus);
- `steps_to_see`: steps until the target was first in view (0 if in view at reset; NaN if never);
- `steps_to_success`: steps until the first success (NaN if none);
- `spl`: success weighted by path length over steps, S * L / max(P, L), with P = `steps_to_success` and
  L the reference shortest step count: the fewer of the agent's own steps and those of a privileged
  servo (`reference_steps`: the scripted servo that knows from the start which way the target lies and
  orbits that way first) on the same seed. So SPL = 1 means "as short as the best path we know of";
- `final_share`: the target's share of the image at the last step; `return`: the sum of rewards.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

import mani_active_vision as mav
from mani_active_vision.box_state import BoxState
from mani_active_vision.recording import RerunRecorder

METRICS = ("success", "success_final", "steps_to_see", "steps_to_success", "spl", "final_share", "return")


def make_box_env(box_source: str = "ground_truth", with_ee_pos: bool = False, image_size: int = 64,
                 record_to: str | None = None, **env_kwargs) -> gym.Env:
    """`ActiveVisionFind-v0` (one env, CPU renderer) with the six directions and the box state; with
    `record_to`, a Rerun recorder (which also shows the box's mask) writes the rollouts to that .rrd file."""
    env = mav.DiscreteDirections(gym.make(
        "ActiveVisionFind-v0", obs_mode="rgb+segmentation", render_backend="cpu",
        sensor_configs=dict(hand_camera=dict(width=image_size, height=image_size)), **env_kwargs))
    if record_to is None:
        return BoxState(env, source=box_source, with_ee_pos=with_ee_pos)
    recorder = RerunRecorder(env, record_to)
    box_env = BoxState(recorder, source=box_source, with_ee_pos=with_ee_pos)
    recorder.show_masks_of(box_env)
    return box_env


def _first(info, key) -> float:
    return float(info[key].reshape(-1)[0])


@dataclass
class Trajectory:
    """What one episode of env 0 did, step by step (entry 0 is the reset)."""

    visible: list = field(default_factory=list)
    success: list = field(default_factory=list)
    share: list = field(default_factory=list)
    rewards: list = field(default_factory=list)

    def start(self, info):
        self.visible, self.success, self.share, self.rewards = [], [], [], []
        self._add(info)

    def append(self, reward, info):
        self.rewards.append(float(torch.as_tensor(reward).reshape(-1)[0]))
        self._add(info)

    def _add(self, info):
        self.visible.append(bool(_first(info, "target_visible")))
        self.success.append(bool(_first(info, "success")))
        self.share.append(_first(info, "target_fraction"))


def _first_index(flags) -> float:
    return float(flags.index(True)) if True in flags else math.nan


def episode_metrics(trajectory: Trajectory, reference_steps: float = math.nan) -> dict:
    """The metrics of one episode (see the module docstring); `reference_steps` NaN = no reference."""
    steps_to_success = _first_index(trajectory.success)
    success = not math.isnan(steps_to_success)
    spl = 0.0
    if success:
        shortest = steps_to_success if math.isnan(reference_steps) else min(reference_steps, steps_to_success)
        spl = shortest / max(steps_to_success, shortest, 1.0) if steps_to_success > 0 else 1.0
    return {"success": float(success), "success_final": float(trajectory.success[-1]),
            "steps_to_see": _first_index(trajectory.visible), "steps_to_success": steps_to_success, "spl": spl,
            "final_share": trajectory.share[-1], "return": float(sum(trajectory.rewards))}


def summarize(episodes: list[dict]) -> dict:
    """Mean and standard deviation of each metric over episodes (steps: over the episodes where they exist)."""
    summary = {"episodes": len(episodes)}
    for key in METRICS:
        values = np.array([e[key] for e in episodes], dtype=float)
        values = values[~np.isnan(values)]
        summary[key] = float(values.mean()) if len(values) else math.nan
        summary[key + "_std"] = float(values.std()) if len(values) else math.nan
    return summary


def run_episode(env, policy, seed: int | None, max_steps: int | None = None, stop_on_success: bool = False) -> Trajectory:
    """One episode of `policy` on env 0 from `env.reset(seed=seed)`, to truncation (or first success)."""
    obs, info = env.reset(seed=seed)
    policy.reset(obs, info)
    trajectory = Trajectory()
    trajectory.start(info)
    for _ in range(max_steps or 10**9):
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
        trajectory.append(reward, info)
        if bool(torch.as_tensor(terminated | truncated).reshape(-1)[0]) or (stop_on_success and trajectory.success[-1]):
            break
    return trajectory


def toward_target_sweep(env) -> str:
    """The orbit direction ("left" = counter-clockwise seen from above) that faces the target soonest:
    privileged (reads the target's position), for the reference only."""
    base = env.unwrapped
    target = base.target.pose.p[0]
    camera = base.agent.controller.target_pos[0]
    turn = math.atan2(float(target[1]), float(target[0])) - math.atan2(float(camera[1]), float(camera[0]))
    turn = (turn + math.pi) % (2 * math.pi) - math.pi
    return "left" if turn > 0 else "right"


def reference_steps(env, seed: int) -> float:
    """Steps to the first success of the privileged servo on this seed (NaN if it does not succeed)."""
    from mani_active_vision.agents.policies import ServoPolicy

    env.reset(seed=seed)
    servo = ServoPolicy(env, first_sweep=toward_target_sweep(env))
    return _first_index(run_episode(env, servo, seed, stop_on_success=True).success)


def evaluate(env, policy, seeds, with_reference: bool = True, desc: str = "evaluate") -> list[dict]:
    """Per-episode metrics of `policy` on the given episode seeds."""
    episodes = []
    for seed in tqdm(list(seeds), desc=desc, leave=False):
        reference = reference_steps(env, seed) if with_reference else math.nan
        metrics = episode_metrics(run_episode(env, policy, seed), reference)
        episodes.append({"seed": int(seed), "reference_steps": reference, **metrics})
    return episodes


def markdown_table(rows: dict[str, dict]) -> str:
    """rows: name -> summary; one row each, mean ± std."""
    header = "| policy | episodes | success | success at end | steps to see | steps to success | SPL | final share | return |"
    lines = [header, "|" + "---|" * 9]
    for name, s in rows.items():
        cell = lambda k, f="{:.2f}": "–" if math.isnan(s[k]) else f"{f.format(s[k])} ± {f.format(s[k + '_std'])}"  # noqa: E731
        lines.append(f"| {name} | {s['episodes']} | {s['success']:.2f} | {s['success_final']:.2f} | {cell('steps_to_see', '{:.1f}')} | "
                     f"{cell('steps_to_success', '{:.1f}')} | {s['spl']:.2f} | {cell('final_share', '{:.3f}')} | {cell('return')} |")
    return "\n".join(lines)


def save_json(data, path: str):
    with open(path, "w") as f:
        json.dump(data, f, indent=2, default=float)


def moving_average(values, window: int) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    kernel = np.ones(min(window, len(values)))
    return np.convolve(values, kernel, "valid") / len(kernel)


def plot_curves(curves: dict[str, list], path: str, ylabel: str, window: int = 10, title: str = ""):
    """Learning curves: label -> per-seed lists of per-episode values; mean ± std over seeds of the
    moving average (window episodes) of each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, runs in curves.items():
        smooth = np.stack([moving_average(r, window) for r in runs])
        mean, std = smooth.mean(0), smooth.std(0)
        x = np.arange(len(mean)) + len(runs[0]) - len(mean) + 1
        ax.plot(x, mean, label=f"{label} ({len(runs)} seed{'s' if len(runs) > 1 else ''})")
        ax.fill_between(x, mean - std, mean + std, alpha=0.25)
    ax.set_xlabel("training episode")
    ax.set_ylabel(f"{ylabel} ({window}-episode moving average)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def perturbation_trial(env, policy, seed: int, push_direction: int, push_steps: int, focus_limit: int = 100, recover_limit: int = 50) -> dict:
    """Run `policy` until the first success (focus), then force `push_steps` steps of `push_direction`
    (the arm is moved away whatever the policy wants), then let the policy act again until success.

    Returns {"focused", "visible_after_push", "recovered", "steps_to_recover" (NaN if not)}. The env needs
    a step limit of at least focus_limit + push_steps + recover_limit (gym.make's max_episode_steps).
    """
    obs, info = env.reset(seed=seed)
    policy.reset(obs, info)
    result = {"focused": False, "visible_after_push": False, "recovered": False, "steps_to_recover": math.nan}
    for _ in range(focus_limit):
        obs, _, _, _, info = env.step(policy.act(obs, info))
        if bool(_first(info, "success")):
            result["focused"] = True
            break
    if not result["focused"]:
        return result
    push = np.full(env.unwrapped.num_envs, push_direction, dtype=np.int64)
    for _ in range(push_steps):
        obs, _, _, _, info = env.step(push)
    result["visible_after_push"] = bool(_first(info, "target_visible"))
    if bool(_first(info, "success")):  # the push did not break focus
        result.update(recovered=True, steps_to_recover=0.0)
        return result
    for step in range(1, recover_limit + 1):
        obs, _, _, _, info = env.step(policy.act(obs, info))
        if bool(_first(info, "success")):
            result.update(recovered=True, steps_to_recover=float(step))
            break
    return result
