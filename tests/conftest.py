"""Shared fixtures: one env per configuration per session (the first make costs seconds: shader compilation)."""

import gymnasium as gym
import pytest
import torch

import mani_active_vision  # noqa: F401  (registers the task)

torch.set_num_threads(1)

_ENVS = {}


def cached_task(**kwargs):
    """A cached `ActiveVisionFind-v0` at 64² (small and fast); callers must reset it themselves."""
    kwargs = {
        "obs_mode": "rgb+segmentation",
        "render_backend": "cpu",
        "sensor_configs": dict(hand_camera=dict(width=64, height=64)),
        **kwargs,
    }
    key = repr(sorted(kwargs.items()))
    if key not in _ENVS:
        _ENVS[key] = gym.make("ActiveVisionFind-v0", **kwargs)
    return _ENVS[key]


@pytest.fixture(scope="session", autouse=True)
def _close_envs():
    yield
    for env in _ENVS.values():
        env.close()
