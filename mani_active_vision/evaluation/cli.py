"""Command lines of scripts that evaluate a DQN checkpoint: its env config is the default of `--env.*`, so
that a flag given overrides that one option and everything else is as the agent was trained."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import tyro

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
