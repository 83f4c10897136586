"""The memory agent's recurrent actor-critic, its input features and its checkpoint files (shared by the
learner `agents.search` and the `memory` policy, as `q_network` is by the DQN's).

The input at step t is `features`: the target's box (x, y, w, h; zeros when unseen), where the camera is
commanded to be (the sine and cosine of its azimuth, its radius and height: where it has looked) and a
one-hot of the agent's own previous action (zeros at an episode's start). A linear layer and a GRU turn the
sequence into a state that remembers where the agent has looked; the policy is a linear head on it (or, with
`actor_sees_input`, a hidden layer on it and the current step's encoding), the value an MLP. The GRU's state
is zero at every episode start (`starts`), in training and in evaluation.

A checkpoint is `{"state_dict", "config"}`: `config` holds the run's arguments (`agents.search.Args` as a
dict, its env config under "env") and `input_dim`, `hidden_units`, `num_actions`; it loads with
`torch.load(..., weights_only=True)`.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import torch
import torch.nn as nn

BOX_DIM, POSITION_DIM, MASK_STATS_DIM = 4, 4, 3
"""The box (x, y, w, h), the camera's commanded position as (sin azimuth, cos azimuth, radius, height) and,
with `EnvConfig(with_mask_stats=True)`, the mask's share of the image and its centroid's offset (dx, dy)."""


STATE_DIMS = (BOX_DIM + 3, BOX_DIM + 4, BOX_DIM + 3 + MASK_STATS_DIM, BOX_DIM + 4 + MASK_STATS_DIM)
"""The box states the memory agent takes: the box and the camera's position, with or without the presence
score and the mask stats."""


def input_dim(num_actions: int, with_mask_stats: bool = False, with_presence: bool = False) -> int:
    return BOX_DIM + POSITION_DIM + with_presence + MASK_STATS_DIM * with_mask_stats + num_actions


def features(box_state: np.ndarray, last_action: np.ndarray, num_actions: int) -> np.ndarray:
    """The network's input (N, input_dim) from the box state with the camera's commanded position (N, 7:
    `EnvConfig(with_ee_pos=True)`; one more with the presence score, `with_presence`, and three more with the
    mask stats, `with_mask_stats`: whatever follows the position is passed on) and each env's previous action
    (N,), -1 at an episode's start."""
    if box_state.shape[-1] not in STATE_DIMS:
        raise ValueError(
            f"the memory agent needs the box with the camera's commanded position (7 numbers, "
            f"EnvConfig(with_ee_pos=True); 8 with_presence, 10 with_mask_stats, 11 with both), got {box_state.shape[-1]}"
        )
    x, y, z = box_state[:, 4], box_state[:, 5], box_state[:, 6]
    azimuth = np.arctan2(y, x)
    position = np.stack([np.sin(azimuth), np.cos(azimuth), np.hypot(x, y), z], -1)
    one_hot = (last_action[:, None] == np.arange(num_actions)).astype(np.float32)
    stats = box_state[:, BOX_DIM + 3 :]
    return np.concatenate([box_state[:, :BOX_DIM], position, stats, one_hot], -1).astype(np.float32)


def layer_init(layer: nn.Linear, std: float = np.sqrt(2), bias: float = 0.0) -> nn.Linear:
    """CleanRL's orthogonal initialisation."""
    nn.init.orthogonal_(layer.weight, std)
    nn.init.constant_(layer.bias, bias)
    return layer


class RecurrentActorCritic(nn.Module):
    """features -> Linear + tanh -> GRU -> policy logits (linear) and value (an MLP on the GRU's output, which
    the value's gradient does not reach: `value`).

    With `actor_sees_input` the policy is Linear + tanh + Linear on the GRU's output beside the current step's
    encoding: a decision its teacher makes from the current box alone (stay while the target is centred and
    large) then need not survive the GRU's state drifting over a long hold."""

    def __init__(self, input_dim: int, num_actions: int, hidden_units: int = 64, actor_sees_input: bool = False):
        super().__init__()
        self.input_dim, self.num_actions, self.hidden_units = input_dim, num_actions, hidden_units
        self.actor_sees_input = actor_sees_input
        self.encoder = nn.Sequential(layer_init(nn.Linear(input_dim, hidden_units)), nn.Tanh())
        self.gru = nn.GRU(hidden_units, hidden_units)
        for name, param in self.gru.named_parameters():
            if "bias" in name:
                nn.init.constant_(param, 0)
            else:
                nn.init.orthogonal_(param, 1.0)
        if actor_sees_input:
            self.actor = nn.Sequential(
                layer_init(nn.Linear(2 * hidden_units, hidden_units)),
                nn.Tanh(),
                layer_init(nn.Linear(hidden_units, num_actions), std=0.01),
            )
        else:
            self.actor = layer_init(nn.Linear(hidden_units, num_actions), std=0.01)
        self.critic = nn.Sequential(
            layer_init(nn.Linear(hidden_units, hidden_units)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden_units, 1), std=1.0),
        )

    def initial_state(self, num_envs: int) -> torch.Tensor:
        return torch.zeros(1, num_envs, self.hidden_units)

    def memory(self, x: torch.Tensor, state: torch.Tensor, starts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The GRU over a sequence x (T, N, input_dim) from `state` (1, N, hidden), zeroing an env's state
        before every step where `starts` (T, N) marks the first observation of an episode. Returns the
        outputs (T, N, hidden) and the state after the last step."""
        encoded = self.encoder(x)
        outputs = []
        for t in range(x.shape[0]):
            state = state * (1.0 - starts[t]).view(1, -1, 1)
            out, state = self.gru(encoded[t : t + 1], state)
            outputs.append(out)
        return torch.cat(outputs), state

    def policy(self, hidden: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Logits (T, N, actions) from the GRU's outputs (T, N, hidden) and the inputs x (T, N, input_dim)."""
        return self.actor(torch.cat([hidden, self.encoder(x)], -1) if self.actor_sees_input else hidden)

    def value(self, hidden: torch.Tensor) -> torch.Tensor:
        """The critic on the GRU's output held fixed: the value's error (returns reach ~20, the policy's
        gradients are small) would otherwise swamp the policy's gradient through the shared GRU."""
        return self.critic(hidden.detach()).squeeze(-1)

    def forward(self, x: torch.Tensor, state: torch.Tensor, starts: torch.Tensor):
        """Logits (T, N, actions), values (T, N) and the state after the sequence."""
        hidden, state = self.memory(x, state, starts)
        return self.policy(hidden, x), self.value(hidden), state


def save_agent(path: str, agent: RecurrentActorCritic, args) -> None:
    """Weights + the run's arguments (a dataclass with a nested `env: EnvConfig`)."""
    config = {
        **dataclasses.asdict(args),
        "input_dim": agent.input_dim,
        "hidden_units": agent.hidden_units,
        "num_actions": agent.num_actions,
        "actor_sees_input": agent.actor_sees_input,
    }
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    torch.save({"state_dict": agent.state_dict(), "config": config}, path)


def load_agent(path: str) -> tuple[RecurrentActorCritic, dict]:
    """The agent of a checkpoint and the config it was trained with (loads with weights_only=True)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"memory agent checkpoint {path!r} does not exist (train one: python -m mani_active_vision.agents.search)"
        )
    checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    config = checkpoint["config"]
    if "input_dim" not in config:
        raise ValueError(f"{path!r} is not a memory agent checkpoint (no input_dim in its config)")
    agent = RecurrentActorCritic(
        config["input_dim"], config["num_actions"], config["hidden_units"], config.get("actor_sees_input", False)
    )
    agent.load_state_dict(checkpoint["state_dict"])
    return agent.eval(), config
