"""The paper's Q-network and its checkpoint files (shared by the DQN learner and the DQN policy).

A checkpoint is `{"state_dict", "config"}`: `config` holds the run's arguments (`agents.dqn.Args` as a dict,
its env config under "env") and the network's `state_dim` and `num_actions` (6 where a checkpoint predates
the optional `stay` action); it loads with `torch.load(..., weights_only=True)`.
"""

from __future__ import annotations

import dataclasses
import os

import torch
import torch.nn as nn

from mani_active_vision.directions import DIRECTIONS
from mani_active_vision.envs import EnvConfig


class QNetwork(nn.Module):
    """The paper's Q-network: state -> one hidden ReLU layer -> a Q-value per direction."""

    def __init__(self, state_dim: int, hidden_units: int = 20, num_actions: int = len(DIRECTIONS)):
        super().__init__()
        self.state_dim, self.num_actions = state_dim, num_actions
        self.network = nn.Sequential(
            nn.Linear(state_dim, hidden_units), nn.ReLU(), nn.Linear(hidden_units, num_actions)
        )

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.network(state)


def save_q_network(path: str, q_network: QNetwork, args) -> None:
    """Weights + the run's arguments (a dataclass with `hidden_units` and a nested `env: EnvConfig`)."""
    config = {**dataclasses.asdict(args), "state_dim": q_network.state_dim, "num_actions": q_network.num_actions}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    torch.save({"state_dict": q_network.state_dict(), "config": config}, path)


def load_q_network(path: str) -> tuple[QNetwork, dict]:
    """The Q-network of a checkpoint and the config it was trained with (loads with weights_only=True)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"DQN checkpoint {path!r} does not exist (train one: python -m mani_active_vision.agents.dqn)"
        )
    checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    config = checkpoint["config"]
    if "env" not in config:
        raise ValueError(f"DQN checkpoint {path!r} has no env config: it predates EnvConfig; train it again")
    q_network = QNetwork(config["state_dim"], config["hidden_units"], config.get("num_actions", len(DIRECTIONS)))
    q_network.load_state_dict(checkpoint["state_dict"])
    return q_network.eval(), config


def checkpoint_env_config(path: str) -> EnvConfig:
    """The env config a checkpoint (the DQN's, or any `{"state_dict", "config": {"env": ...}}` file such as
    the memory agent's) was trained with."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"checkpoint {path!r} does not exist")
    config = torch.load(path, map_location="cpu", weights_only=True)["config"]
    if "env" not in config:
        raise ValueError(f"checkpoint {path!r} has no env config: it predates EnvConfig; train it again")
    return EnvConfig.from_dict(config["env"])
