"""Shared fixtures: one env per configuration per session (the first make costs seconds: shader compilation)."""

import importlib.util
import os
import sys

import gymnasium as gym
import pytest
import torch

from mani_active_vision.envs import EnvConfig

torch.set_num_threads(1)

_ENVS = {}
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


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


@pytest.fixture
def baseline_script(monkeypatch):
    """`load(name)`: the script baselines/<name>.py imported as a module, to test its functions (registered in
    sys.modules for the test: its dataclasses look their module up there)."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "baselines", f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, name, module)
        spec.loader.exec_module(module)
        return module

    return load
