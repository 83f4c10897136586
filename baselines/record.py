"""Record episodes of a policy in ActiveVisionFind-v0 to a Rerun file, and say how to look at it.

    python baselines/record.py --policy random --episodes 2 --seed 0 --out recordings/random.rrd
    rerun recordings/random.rrd                                   # the viewer
    python baselines/screenshots.py recordings/random.rrd --steps 20 60   # PNGs without a viewer
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import gymnasium as gym
import torch
import tyro

import mani_active_vision as mav
from mani_active_vision.agents.policies import POLICIES, make_policy, policy_kwargs
from mani_active_vision.box_state import BoxState
from mani_active_vision.recording import RerunRecorder, record_rollouts


@dataclass
class Args:
    policy: str = "random"
    """policy name, one of mani_active_vision.agents.policies.POLICIES: random, explore, servo, dqn"""
    episodes: int = 2
    """episodes to record (100 steps each)"""
    seed: int = 0
    """seed of the first episode; episode k uses seed + k"""
    out: str = "recordings/random.rrd"
    """the .rrd file to write (its folder is created)"""
    then: str = "none"
    """for --policy explore: the policy that takes over once the target is seen (servo, dqn, random, none)"""
    checkpoint: str = ""
    """a DQN checkpoint (q_network.pt), for --policy dqn or --then dqn"""
    box_source: str | None = "ground_truth"
    """wrap the env in BoxState(source=...) (ground_truth or fcn): the policy sees the box, the recording
    also shows the mask the box came from; none: the policy sees the raw observation (random only)"""
    image_format: str = "jpeg"
    """wrist RGB as jpeg (small) or raw"""
    jpeg_quality: int = 90
    """JPEG quality, 1-100"""
    image_size: int = 128
    """side of the wrist camera image in pixels"""
    start_pose: str = "search"
    """sky (the paper's) or search"""
    object_set: str = "train"
    """train, unseen or primitives"""
    placement: str = "random"
    """random or fixed"""


def main(args: Args):
    torch.set_num_threads(1)
    if args.policy not in POLICIES:  # before any file is written
        raise ValueError(f"policy={args.policy!r} is not one of: {', '.join(POLICIES)}")
    env = mav.DiscreteDirections(gym.make(
        "ActiveVisionFind-v0", obs_mode="rgb+segmentation", render_backend="cpu", start_pose=args.start_pose,
        object_set=args.object_set, placement=args.placement,
        sensor_configs=dict(hand_camera=dict(width=args.image_size, height=args.image_size))))
    recorder = RerunRecorder(env, args.out, image_format=args.image_format, jpeg_quality=args.jpeg_quality)
    env = recorder
    if args.box_source not in (None, "none"):
        env = BoxState(recorder, source=args.box_source)
        recorder.show_masks_of(env)
    try:
        policy = make_policy(args.policy, env, **policy_kwargs(args.policy, args.then, args.checkpoint, args.seed))
        results = record_rollouts(env, policy, args.episodes, seed=args.seed)
    finally:
        env.close()  # writes the file's footer, also on an exception or Ctrl-C
    for r in results:
        print(f"episode {r['episode']} env {r['env']}: {r['steps']} steps, return {r['ret']:.3f}, success at the end {r['success']}")
    cost = recorder.overhead()
    size = os.path.getsize(args.out)
    print(f"logging {cost['log_ms_per_step']:.1f} ms/step = {100 * cost['log_share_of_env_step']:.0f}% of an env step "
          f"({cost['env_ms_per_step']:.1f} ms), resets {cost['reset_log_seconds']:.2f} s in all; file {size / 1e6:.2f} MB = {size / 1e6 / cost['steps'] * 100:.2f} MB per 100 steps")
    print(f"wrote {args.out}\nopen it:        {os.path.join('.venv', 'bin', 'rerun')} {args.out}"
          f"\nscreenshots:    python baselines/screenshots.py {args.out} --steps 20 60")


if __name__ == "__main__":
    main(tyro.cli(Args))
