"""The evaluation protocol: fixed episode seeds from `EVAL_SEED` (never a training scene), the metrics of
each episode (`mani_active_vision.metrics`) with SPL measured against the privileged reference."""

from __future__ import annotations

import math

from tqdm import tqdm

from mani_active_vision.evaluation.reference import reference_steps
from mani_active_vision.evaluation.rollout import run_episode, stop_on_ctrl_c
from mani_active_vision.metrics import episode_metrics

EVAL_SEED = 1_000_000
"""The first evaluation episode's seed; training seeds stay below it (agents.dqn.TRAIN_SEED_STRIDE)."""


def eval_seeds(episodes: int, first: int = EVAL_SEED) -> range:
    return range(first, first + episodes)


def evaluate(
    env, policy, seeds, with_reference: bool = True, desc: str = "evaluate", progress: bool = True
) -> list[dict]:
    """Per-episode metrics of `policy` on the given episode seeds (with the reference's steps for SPL)."""
    episodes = []
    with stop_on_ctrl_c() as stop_requested:  # also between episodes: a reset is never cut in half
        for seed in tqdm(list(seeds), desc=desc, leave=False, disable=not progress):
            if stop_requested():
                raise KeyboardInterrupt(f"stopped by Ctrl-C after {len(episodes)} episodes")
            reference = reference_steps(env, seed) if with_reference else math.nan
            metrics = episode_metrics(run_episode(env, policy, seed), reference)
            episodes.append({"seed": int(seed), "reference_steps": reference, **metrics})
    return episodes
