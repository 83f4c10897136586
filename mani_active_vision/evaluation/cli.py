"""Command lines whose `--env.*` defaults come from elsewhere, so that a flag given overrides that one option:
scripts that evaluate a DQN checkpoint (its env config, everything else as the agent was trained), and scripts
that train a DQN preset (the preset's env: `hold_stay` acts with `stay` and the mask stats)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import tyro

from mani_active_vision.agents import dqn
from mani_active_vision.agents.q_network import checkpoint_env_config


def cli_with_checkpoint_env(args_type, argv: list[str] | None = None):
    """`tyro.cli(args_type)`; when `--checkpoint PATH` is given, the defaults of the nested `env` field are
    that checkpoint's env config (`--help` then shows them). `args_type` has fields `checkpoint` and `env`."""
    argv = sys.argv[1:] if argv is None else argv
    peek = argparse.ArgumentParser(add_help=False)
    peek.add_argument("--checkpoint", default="")
    checkpoint = peek.parse_known_args(argv)[0].checkpoint
    default = args_type()
    if checkpoint:
        default = dataclasses.replace(default, checkpoint=checkpoint, env=checkpoint_env_config(checkpoint))
    return tyro.cli(args_type, default=default, args=argv)


def cli_with_preset_env(args_type, argv: list[str] | None = None):
    """`tyro.cli(args_type)` with the defaults of the nested `env` field those of the DQN preset that `--preset`
    names (or `args_type`'s default preset); `--help` then shows them. `args_type` has fields `preset` and `env`."""
    argv = sys.argv[1:] if argv is None else argv
    default = args_type()
    peek = argparse.ArgumentParser(add_help=False)
    peek.add_argument("--preset", default=default.preset)
    preset = peek.parse_known_args(argv)[0].preset
    if preset not in dqn.PRESETS:
        raise ValueError(f"preset={preset!r} is not one of: {', '.join(dqn.PRESETS)}")
    return tyro.cli(args_type, default=dataclasses.replace(default, env=dqn.PRESETS[preset][1].env), args=argv)
