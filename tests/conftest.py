"""Shared fixtures: one env per configuration per session (the first make costs seconds: shader compilation)."""

import gymnasium as gym
import pytest
import torch

from mani_active_vision.envs import EnvConfig

torch.set_num_threads(1)

_ENVS = {}


def cached_task(**kwargs):
    """A cached raw `ActiveVisionFind-v0` (the default `EnvConfig`'s task: 64², small and fast) with the
    task's keyword arguments `kwargs` on top; callers must reset it themselves."""
    kwargs = {**EnvConfig().task_kwargs(), **kwargs}
    key = repr(sorted(kwargs.items()))
    if key not in _ENVS:
        _ENVS[key] = gym.make("ActiveVisionFind-v0", **kwargs)
    return _ENVS[key]


@pytest.fixture(scope="session", autouse=True)
def _close_envs():
    yield
    for env in _ENVS.values():
        env.close()
