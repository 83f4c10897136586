"""Record episodes of a policy in ActiveVisionFind-v0 to a Rerun file, and say how to look at it.

    python baselines/record.py --policy servo --episodes 2 --out recordings/servo.rrd
    python baselines/record.py --policy random --env.box-source none --env.image-size 128   # raw observations
    rerun recordings/servo.rrd                                    # the viewer
    python baselines/screenshots.py recordings/servo.rrd --steps 20 60   # PNGs without a viewer

With a DQN checkpoint the env is the one it was trained in (each `--env.*` flag given overrides that option).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import torch

from mani_active_vision.agents.policies import POLICIES, make_policy, policy_kwargs
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.protocol import evaluate
from mani_active_vision.recording import RerunRecorder


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env; box_source none gives the policy the raw observation (random only); the recording shows the
    mask the box came from"""
    policy: str = "random"
    """policy name, one of mani_active_vision.agents.policies.POLICIES: random, explore, servo, dqn, memory"""
    episodes: int = 2
    """episodes to record"""
    seed: int = 0
    """seed of the first episode; episode k uses seed + k"""
    out: str = "recordings/random.rrd"
    """the .rrd file to write (its folder is created)"""
    then: str = "none"
    """for --policy explore: the policy that takes over once the target is seen (servo, dqn, random, none)"""
    checkpoint: str = ""
    """a DQN checkpoint (q_network.pt), for --policy dqn or --then dqn; the memory agent's for --policy memory"""
    look_over: bool = False
    """for --policy servo or explore, on scenes with --env.occluders: the sweep first looks over the panels and the
    servo approaches from above (docs/task.md#occluders)"""
    image_format: str = "jpeg"
    """wrist RGB as jpeg (small) or raw"""
    jpeg_quality: int = 90
    """JPEG quality, 1-100"""


def main(args: Args):
    torch.set_num_threads(1)
    if args.policy not in POLICIES:  # before any file is written
        raise ValueError(f"policy={args.policy!r} is not one of: {', '.join(POLICIES)}")
    kwargs = policy_kwargs(args.policy, args.then, args.checkpoint, args.seed, look_over=args.look_over)
    with RerunRecorder(
        make_env(args.env), args.out, image_format=args.image_format, jpeg_quality=args.jpeg_quality
    ) as env:
        policy = make_policy(args.policy, env, **kwargs)
        episodes = evaluate(
            env, policy, range(args.seed, args.seed + args.episodes), with_reference=False, desc="record"
        )
    for e in episodes:
        print(
            f"episode seed {e['seed']}: return {e['return']:.3f}, success {bool(e['success'])}, "
            f"success at the end {bool(e['success_final'])}"
        )
    cost = env.overhead()
    size = os.path.getsize(args.out)
    print(
        f"logging {cost['log_ms_per_step']:.1f} ms/step = {100 * cost['log_share_of_env_step']:.0f}% of an env step "
        f"({cost['env_ms_per_step']:.1f} ms), resets {cost['reset_log_seconds']:.2f} s in all; file {size / 1e6:.2f} MB = "
        f"{size / 1e6 / max(cost['steps'], 1) * 100:.2f} MB per 100 steps"
    )
    print(
        f"wrote {args.out}\nopen it:        {os.path.join('.venv', 'bin', 'rerun')} {args.out}"
        f"\nscreenshots:    python baselines/screenshots.py {args.out} --steps 20 60"
    )


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
