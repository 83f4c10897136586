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
    """The paper's Q-network: state -> one hidden ReLU layer -> a Q-value per direction.

    With `ensemble` K > 1, K such networks side by side, each from its own initialisation: the Q-value is their
    mean (what the agent acts on), `member_values` each one's (what each learns from; `agents.dqn.td_loss`).
    One network's Q-values are noisy where success begins, and a greedy policy turns that noise into cycles
    next to success; the mean of several is meant to be steadier. Measured (docs/control.md §8): members
    trained in one run of 100 episodes did not gain success; networks trained on different episodes did."""

    def __init__(self, state_dim: int, hidden_units: int = 20, num_actions: int = len(DIRECTIONS), ensemble: int = 1):
        super().__init__()
        if not (isinstance(ensemble, int) and ensemble >= 1):
            raise ValueError(f"ensemble={ensemble!r} must be a positive integer (1: one network, the paper's)")
        self.state_dim, self.num_actions, self.ensemble = state_dim, num_actions, ensemble

        def network():
            return nn.Sequential(nn.Linear(state_dim, hidden_units), nn.ReLU(), nn.Linear(hidden_units, num_actions))

        if ensemble == 1:  # the paper's network, as every checkpoint before ensembles stores it
            self.network = network()
        else:
            self.members = nn.ModuleList(network() for _ in range(ensemble))

    def member(self, k: int) -> nn.Module:
        """The k-th network (k = 0: the one network)."""
        return self.network if self.ensemble == 1 else self.members[k]

    def member_values(self, state: torch.Tensor) -> torch.Tensor:
        """(K, N, actions): each member's Q-values."""
        return torch.stack([self.member(k)(state) for k in range(self.ensemble)])

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        if self.ensemble == 1:
            return self.network(state)
        return self.member_values(state).mean(0)


def save_q_network(path: str, q_network: QNetwork, args) -> None:
    """Weights + the run's arguments (a dataclass with `hidden_units` and a nested `env: EnvConfig`)."""
    config = {
        **dataclasses.asdict(args),
        "state_dim": q_network.state_dim,
        "num_actions": q_network.num_actions,
        "members": q_network.ensemble,  # trained side by side (args.ensemble) or snapshots of one (args.snapshots)
    }
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
    q_network = QNetwork(
        config["state_dim"],
        config["hidden_units"],
        config.get("num_actions", len(DIRECTIONS)),
        config.get("members", config.get("ensemble", 1)),  # checkpoints before snapshots say ensemble only
    )
    q_network.load_state_dict(checkpoint["state_dict"])
    return q_network.eval(), config


def ensemble_of(template: QNetwork, states: list[dict]) -> QNetwork:
    """A network of `template`'s shape per state dict (each one network's), side by side as one ensemble that
    acts on their mean Q: one run's snapshots (`dqn.Args.snapshots`) or several runs (`ensemble_checkpoint`)."""
    hidden_units = template.member(0)[0].out_features
    ensemble = QNetwork(template.state_dim, hidden_units, template.num_actions, len(states))
    for k, state in enumerate(states):
        ensemble.member(k).load_state_dict(state)
    return ensemble


def ensemble_checkpoint(paths: list[str]) -> dict:
    """One checkpoint whose network is the given DQN checkpoints' networks side by side (`QNetwork(ensemble=K)`,
    acting on the mean of their Q-values), with the first one's config: runs of one preset from other seeds,
    whose networks learned from different episodes and so err less alike than one run's (docs/control.md §14).
    Each must hold one network of the first one's shape, trained in the same env; else a ValueError."""
    networks, configs = zip(*(load_q_network(path) for path in paths))
    first = configs[0]
    for path, network, config in zip(paths, networks, configs):
        if network.ensemble != 1:
            raise ValueError(f"{path!r} holds {network.ensemble} networks: give the runs' own checkpoints")
        for key in ("state_dim", "num_actions", "hidden_units", "env"):
            if config.get(key) != first.get(key):
                raise ValueError(f"{path!r} differs from {paths[0]!r} in {key}: {config.get(key)} != {first.get(key)}")
    ensemble = ensemble_of(networks[0], [network.member(0).state_dict() for network in networks])
    config = {
        **first,
        "members": len(paths),
        "member_seeds": [config["seed"] for config in configs],
        "member_episodes": sum(config["episodes"] for config in configs),
    }
    return {"state_dict": ensemble.state_dict(), "config": config}


def checkpoint_env_config(path: str) -> EnvConfig:
    """The env config a checkpoint (the DQN's, or any `{"state_dict", "config": {"env": ...}}` file such as
    the memory agent's) was trained with."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"checkpoint {path!r} does not exist")
    config = torch.load(path, map_location="cpu", weights_only=True)["config"]
    if "env" not in config:
        raise ValueError(f"checkpoint {path!r} has no env config: it predates EnvConfig; train it again")
    return EnvConfig.from_dict(config["env"])
