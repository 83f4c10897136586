"""What one episode did, and the metrics made of it (pure functions: training and evaluation share them).

Metrics of one episode (`episode_metrics`), steps counted in actions taken:
- `success`: the task's success held at some step; `success_final`: it holds at the last step (kept focus);
- `focus_held`: the share of the observations from the first success to the episode's last one (both
  counted) that are in success: 1 = never lost once found, 1/k = found, then lost for the k - 1 steps to
  the end. NaN when never successful (there is no focus to hold); the mean over episodes (`summarize`)
  is over the successful episodes only, so read it with `success` beside it. An episode that ends at its
  first success (`terminate_on_success`) holds it trivially (1);
- `steps_to_see`: steps until the target was first in view (0 if in view at reset; NaN if never);
- `steps_to_success`: steps until the first success (NaN if none);
- `spl`: success weighted by path length over steps, S * L / max(P, L), with P = `steps_to_success` and
  L the reference shortest step count: the fewer of the agent's own steps and those of a privileged
  servo on the same seed (`evaluation.reference`). So SPL = 1 means "as short as the best path we know of";
  NaN without a reference run;
- `final_target_fraction`: the target's share of the image at the last step; `return`: the sum of rewards.
NaN marks "does not exist" in memory; JSON files hold `null` there (`json_io`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

METRICS = (
    "success",
    "success_final",
    "focus_held",
    "steps_to_see",
    "steps_to_success",
    "spl",
    "final_target_fraction",
    "return",
)


def first_env(info: dict, key: str) -> float:
    """`info[key]` of env 0, as a float (batched torch or unbatched numpy info alike)."""
    return float(torch.as_tensor(info[key]).reshape(-1)[0])


@dataclass
class Trajectory:
    """What one episode of env 0 did, step by step (entry 0 is the reset)."""

    visible: list = field(default_factory=list)
    success: list = field(default_factory=list)
    target_fraction: list = field(default_factory=list)
    rewards: list = field(default_factory=list)

    def start(self, info: dict):
        self.visible, self.success, self.target_fraction, self.rewards = [], [], [], []
        self._add(info)

    def append(self, reward, info: dict):
        self.rewards.append(float(torch.as_tensor(reward).reshape(-1)[0]))
        self._add(info)

    def _add(self, info: dict):
        self.visible.append(bool(first_env(info, "target_visible")))
        self.success.append(bool(first_env(info, "success")))
        self.target_fraction.append(first_env(info, "target_fraction"))


def first_index(flags: list) -> float:
    """The index of the first True in `flags`, NaN if none."""
    return float(flags.index(True)) if True in flags else math.nan


def focus_held(success: list) -> float:
    """The share of `success` flags from the first True to the end that are True (NaN if none is)."""
    first = first_index(success)
    if math.isnan(first):
        return math.nan
    held = success[int(first) :]
    return sum(held) / len(held)


def episode_metrics(trajectory: Trajectory, reference_steps: float | None = None) -> dict:
    """The metrics of one episode (see the module docstring); `reference_steps` None = no reference run (SPL
    NaN), NaN = the reference ran and did not succeed (the agent's own steps are the shortest known)."""
    steps_to_success = first_index(trajectory.success)
    success = not math.isnan(steps_to_success)
    spl = math.nan if reference_steps is None else 0.0
    if success and reference_steps is not None:
        shortest = steps_to_success if math.isnan(reference_steps) else min(reference_steps, steps_to_success)
        spl = shortest / max(steps_to_success, shortest, 1.0) if steps_to_success > 0 else 1.0
    return {
        "success": float(success),
        "success_final": float(trajectory.success[-1]),
        "focus_held": focus_held(trajectory.success),
        "steps_to_see": first_index(trajectory.visible),
        "steps_to_success": steps_to_success,
        "spl": spl,
        "final_target_fraction": trajectory.target_fraction[-1],
        "return": float(sum(trajectory.rewards)),
    }


def summarize(episodes: list[dict]) -> dict:
    """Mean and standard deviation of each metric over episodes (steps and focus held: over the episodes
    where they exist, i.e. that saw the target / succeeded)."""
    summary = {"episodes": len(episodes)}
    for key in METRICS:
        values = np.array([e[key] for e in episodes], dtype=float)
        values = values[~np.isnan(values)]
        summary[key] = float(values.mean()) if len(values) else math.nan
        summary[key + "_std"] = float(values.std()) if len(values) else math.nan
    return summary
