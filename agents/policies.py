"""Policies with one interface, over `DiscreteDirections` actions.

A policy is built by `make_policy(name, env, **kwargs)` on the env it will act in (a ManiSkill env,
possibly wrapped; batched or not), and then:
- `policy.reset(obs, info)` at the start of every episode (for batched envs: whenever any env resets),
- `policy.act(obs, info) -> np.ndarray` of direction indices (N,) int64, one per env.
`obs` and `info` are what the wrapped env returned. Names: see POLICIES.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from mani_active_vision.directions import DIRECTIONS


class RandomPolicy:
    """Uniformly random directions (a lower bound)."""

    def __init__(self, env, seed: int = 0):
        self.num_envs = env.unwrapped.num_envs
        self.rng = np.random.default_rng(seed)

    def reset(self, obs, info):
        pass

    def act(self, obs, info) -> np.ndarray:
        return self.rng.integers(0, len(DIRECTIONS), size=self.num_envs)


POLICIES: dict[str, Callable] = {"random": RandomPolicy}


def make_policy(name: str, env, **kwargs):
    if name not in POLICIES:
        raise ValueError(f"policy={name!r} is not one of: {', '.join(POLICIES)}")
    return POLICIES[name](env, **kwargs)
