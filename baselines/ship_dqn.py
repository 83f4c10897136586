"""Make a DQN checkpoint the shipped agent: a copy whose env (what evaluation starts from) is the deployed one,
the FCN's box on unseen objects at 128², held through the FCN's misses, with the env it was trained in kept
as config["trained_env"].

    python baselines/ship_dqn.py --checkpoint runs/make_dqn/shipped/q_network.pt --out agents/weights/dqn.pt

scripts/make_dqn.sh makes the shipped agent this way; `baselines/evaluate.py --policy explore --then dqn
--checkpoint agents/weights/dqn.pt` then evaluates it as deployed. Any `{"state_dict", "config": {"env"}}`
checkpoint ships the same way: scripts/make_search.sh ships the memory agent (agents/search.py) with it.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.envs import FCN_BOX_HOLD_STEPS, FCN_IMAGE_SIZE, EnvConfig


@dataclass
class Args:
    checkpoint: str
    """the trained checkpoint (a DQN's q_network.pt, or the memory agent's agent.pt)"""
    out: str = "agents/weights/dqn.pt"
    """where the shipped checkpoint goes"""
    box_source: str = "fcn"
    """the deployed box: the FCN's (as in the paper)"""
    object_set: str = "unseen"
    """the deployed objects: never seen in training"""
    image_size: int = FCN_IMAGE_SIZE
    """the deployed camera's side (the FCN's box is deployed at 128²: envs.FCN_IMAGE_SIZE)"""
    box_hold_steps: int = FCN_BOX_HOLD_STEPS
    """the deployed box keeps the last box seen this many steps while the FCN sees nothing (envs.FCN_BOX_HOLD_STEPS)"""


def ship(args: Args) -> EnvConfig:
    """Copy the checkpoint with the deployed env (its training env with the box, its hold, the objects and the
    camera's side changed)."""
    saved = torch.load(args.checkpoint, map_location="cpu", weights_only=True)
    config = saved["config"]
    trained = config.get("trained_env", config["env"])
    env = EnvConfig.from_dict(trained).replace(
        box_source=args.box_source,
        object_set=args.object_set,
        image_size=args.image_size,
        box_hold_steps=args.box_hold_steps,
    )
    saved["config"] = {**config, "env": dataclasses.asdict(env), "trained_env": trained}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    torch.save(saved, args.out)
    return env


if __name__ == "__main__":
    args = tyro.cli(Args)
    env = ship(args)
    print(f"{args.checkpoint} -> {args.out}: deployed on the {env.box_source} box, {env.object_set} objects")
