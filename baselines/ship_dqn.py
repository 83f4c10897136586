"""Make a DQN checkpoint the shipped agent: a copy whose env (what evaluation starts from) is the deployed one,
the FCN's box on unseen objects at 128², held through the FCN's misses (and, if asked, the fine moves near the
target), with the env it was trained in kept as config["trained_env"].

    python baselines/ship_dqn.py --checkpoint runs/make_dqn/shipped/q_network.pt --out agents/weights/dqn.pt --as-dqn

scripts/make_dqn.sh makes the shipped agent this way (`--as-dqn`: `EnvConfig.as_dqn_deployed`);
`baselines/evaluate.py --policy explore --then dqn --checkpoint agents/weights/dqn.pt` then evaluates it as
deployed. Any `{"state_dict", "config": {"env"}}` checkpoint ships the same way: scripts/make_search.sh ships the
memory agent (agents/search.py) with it. With `--members`, several DQN runs ship as one agent acting on their mean
Q (scripts/make_dqn_ensemble.sh).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.agents.q_network import ensemble_checkpoint
from mani_active_vision.envs import FCN_BOX_HOLD_STEPS, EnvConfig


@dataclass
class Args:
    checkpoint: str
    """the trained checkpoint (a DQN's q_network.pt, or the memory agent's agent.pt)"""
    members: tuple[str, ...] = ()
    """more DQN checkpoints (the same preset's runs from other seeds) to act with `checkpoint` as one agent, on
    the mean of their Q-values (`q_network.ensemble_checkpoint`; their training episodes add up;
    scripts/make_dqn_ensemble.sh)"""
    out: str = "agents/weights/dqn.pt"
    """where the shipped checkpoint goes"""
    as_dqn: bool = False
    """deploy it as the shipped DQNs are (`EnvConfig.as_dqn_deployed`: the verifier's bars, the FCN's segmenting
    size, the fine moves and their zone, the step back when too close, of envs' DQN constants, `stay` only in success,
    the held box moving with the camera; scripts/make_dqn.sh);
    the options below, where given, still override"""
    object_set: str = "unseen"
    """the deployed objects: never seen in training"""
    box_hold_steps: int = FCN_BOX_HOLD_STEPS
    """how many steps the deployed box keeps the last box seen while the FCN sees nothing
    (default: `EnvConfig.on_fcn_box`'s, envs.FCN_BOX_HOLD_STEPS)"""
    fcn_acquire_threshold: float = 0.0
    """the verifier probability a new region of the deployed box needs (0: the FCN checkpoint's own bar, or with
    --as-dqn envs.DQN_FCN_THRESHOLDS')"""
    fcn_track_threshold: float = 0.0
    """the verifier probability a region near the last box needs to stay the box (0: the FCN checkpoint's, or with
    --as-dqn the DQNs')"""
    fine_step_size: float | None = None
    """the deployed env's fine moves (0: none; None: those it was trained with, or with --as-dqn
    envs.DQN_FINE_STEP_SIZE: half steps near the target, for a DQN trained with them or on the full step)"""
    fcn_segment_size: int | None = None
    """the side the deployed FCN segments the camera's frame at (`EnvConfig.fcn_segment_size`; 0: the network's
    training size; None: the trained env's, or with --as-dqn envs.FCN_SEGMENT_SIZE, the camera's own 128²,
    docs/control.md §17)"""
    stay_needs_success: bool = False
    """deploy it to take `stay` only where the box's mask stats show success (`EnvConfig.stay_needs_success`; with
    --as-dqn it is on already where the state has the mask stats; scripts/make_search_occluded.sh)"""
    held_box_tracking: bool = False
    """deploy it with the held box moving as the camera does and dropped once centred and unseen
    (`EnvConfig.with_held_box_tracking`; with --as-dqn it is on already; scripts/make_search_occluded.sh)"""
    fine_near_centre: float | None = None
    """how far from the image centre the deployed policy takes the fine moves (`EnvConfig.fine_near_centre`;
    None: the trained env's, or with --as-dqn envs.DQN_FINE_NEAR_CENTRE, docs/control.md §18)"""


def ship(args: Args) -> EnvConfig:
    """Copy the checkpoint with the deployed env: its training env on the FCN's box as deployed
    (`EnvConfig.on_fcn_box`), with the deployed objects."""
    if args.members:
        saved = ensemble_checkpoint([args.checkpoint, *args.members])
    else:
        saved = torch.load(args.checkpoint, map_location="cpu", weights_only=True)
    config = saved["config"]
    trained = config.get("trained_env", config["env"])
    bars = {"fcn_acquire_threshold": args.fcn_acquire_threshold, "fcn_track_threshold": args.fcn_track_threshold}
    env = EnvConfig.from_dict(trained)
    if args.as_dqn:  # each bar given overrides the DQNs'
        env = env.as_dqn_deployed().replace(**{name: bar for name, bar in bars.items() if bar})
    else:
        env = env.on_fcn_box(tuple(bars.values()))
    if args.held_box_tracking:
        env = env.with_held_box_tracking()
    held = args.box_hold_steps > 0  # nothing held: nothing to move or drop
    env = env.replace(
        object_set=args.object_set,
        box_hold_steps=args.box_hold_steps,
        box_hold_follows_camera=env.box_hold_follows_camera and held,
        box_hold_drop_centred=env.box_hold_drop_centred if held else 0,
    )
    if args.fine_step_size is not None:
        env = env.replace(fine_step_size=args.fine_step_size)
    if args.fcn_segment_size is not None:
        env = env.replace(fcn_segment_size=args.fcn_segment_size)
    if args.fine_near_centre is not None:
        env = env.replace(fine_near_centre=args.fine_near_centre)
    if args.stay_needs_success:
        env = env.replace(stay_needs_success=True)
    saved["config"] = {**config, "env": dataclasses.asdict(env), "trained_env": trained}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    torch.save(saved, args.out)
    return env


if __name__ == "__main__":
    args = tyro.cli(Args)
    env = ship(args)
    print(f"{args.checkpoint} -> {args.out}: deployed on the {env.box_source} box, {env.object_set} objects")
