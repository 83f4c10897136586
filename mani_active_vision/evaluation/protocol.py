"""The evaluation protocol: fixed episode seeds from `EVAL_SEED` (never a training scene), the metrics of
each episode (`mani_active_vision.metrics`) with SPL measured against the privileged reference."""

from __future__ import annotations

from tqdm import tqdm

from mani_active_vision.evaluation.reference import reference_steps
from mani_active_vision.evaluation.rollout import run_episode, stop_on_ctrl_c
from mani_active_vision.metrics import episode_metrics

EVAL_SEED = 1_000_000
"""The first evaluation episode's seed; training seeds stay below it (agents.dqn.TRAIN_SEED_STRIDE)."""


def eval_seeds(episodes: int, first: int = EVAL_SEED) -> range:
    return range(first, first + episodes)


def evaluate(
    env,
    policy,
    seeds,
    with_reference: bool = True,
    desc: str = "evaluate",
    progress: bool = True,
    references: dict[int, float] | None = None,
) -> list[dict]:
    """Per-episode metrics of `policy` on the given episode seeds (with the reference's steps for SPL).
    `references`: the reference's steps by seed, measured before on the same env (`reference_table`), so
    that several policies on the same seeds need not run the reference again."""
    episodes = []
    with stop_on_ctrl_c() as stop_requested:  # also between episodes: a reset is never cut in half
        for seed in tqdm(list(seeds), desc=desc, leave=False, disable=not progress):
            if stop_requested():
                raise KeyboardInterrupt(f"stopped by Ctrl-C after {len(episodes)} episodes")
            if references is not None:
                if int(seed) not in references:
                    raise KeyError(f"references has no steps for seed {seed}; it has seeds {sorted(references)}")
                reference = references[int(seed)]
            else:
                reference = reference_steps(env, seed) if with_reference else None
            metrics = episode_metrics(run_episode(env, policy, seed), reference)
            episodes.append({"seed": int(seed), "reference_steps": reference, **metrics})
    return episodes


def reference_table(env, seeds, progress: bool = True) -> dict[int, float]:
    """The privileged reference's steps to success on each seed (NaN where it does not succeed)."""
    return {
        int(s): reference_steps(env, s) for s in tqdm(list(seeds), desc="reference", leave=False, disable=not progress)
    }
