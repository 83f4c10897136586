"""Evaluate a policy on fixed episode seeds: success, steps to first see the target, SPL, final share, return.

    python baselines/evaluate.py --policy servo --episodes 20
    python baselines/evaluate.py --policy explore --then dqn --checkpoint runs/dqn/random_explore_seed0/q_network.pt

Episode seeds are `seed, seed+1, ...` (default from 1,000,000: never a training scene). The env options of
a DQN checkpoint (placement, link state, image size, ...) are taken from its config unless given here.
Prints a markdown table and writes the per-episode metrics and their summary as JSON.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import tyro

from mani_active_vision.agents.dqn import load_q_network
from mani_active_vision.agents.evaluation import evaluate, make_box_env, markdown_table, save_json, summarize
from mani_active_vision.agents.policies import make_policy, policy_kwargs


@dataclass
class Args:
    policy: str = "servo"
    """random, explore, servo or dqn"""
    then: str = "none"
    """for --policy explore: who takes over once the target is seen (dqn, servo, random, none)"""
    checkpoint: str = ""
    """a DQN checkpoint (q_network.pt), for --policy dqn or --then dqn"""
    epsilon: float = 0.0
    """for a DQN: the share of random actions (ε-greedy; 0 = greedy)"""
    episodes: int = 20
    """evaluation episodes"""
    seed: int = 1_000_000
    """seed of the first episode (then +1 each) and of the policy's randomness"""
    placement: str = ""
    """random or fixed (default: the checkpoint's, else random)"""
    with_ee_pos: bool | None = None
    """link state in the box state (default: the checkpoint's, else off)"""
    box_source: str = ""
    """ground_truth or fcn (default: the checkpoint's, else ground_truth)"""
    image_size: int = 0
    """wrist camera side (default: the checkpoint's, else 64)"""
    num_objects: int = 5
    """objects on the floor"""
    object_set: str = "train"
    """train, unseen or primitives"""
    start_pose: str = "sky"
    """sky or search"""
    reference: bool = True
    """also run the privileged servo on each seed, for SPL's shortest step count"""
    json: str = "outputs/evaluate.json"
    """where the metrics go"""


def env_options(args: Args) -> dict:
    config = load_q_network(args.checkpoint)[1] if args.checkpoint else {}
    pick = lambda given, key, default: given if given not in ("", 0, None) else config.get(key, default)  # noqa: E731
    return dict(placement=pick(args.placement, "placement", "random"), with_ee_pos=bool(pick(args.with_ee_pos, "with_ee_pos", False)),
                box_source=pick(args.box_source, "box_source", "ground_truth"), image_size=pick(args.image_size, "image_size", 64),
                num_objects=args.num_objects, object_set=args.object_set, start_pose=args.start_pose)


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    options = env_options(args)
    env = make_box_env(**options)
    policy = make_policy(args.policy, env, **policy_kwargs(args.policy, args.then, args.checkpoint, args.seed, args.epsilon))
    name = args.policy + (f"→{args.then}" if args.policy == "explore" and args.then != "none" else "")
    episodes = evaluate(env, policy, range(args.seed, args.seed + args.episodes), with_reference=args.reference, desc=name)
    env.close()
    summary = summarize(episodes)
    print(markdown_table({name: summary}))
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    save_json({"policy": name, "checkpoint": args.checkpoint, "env": options, "summary": summary, "episodes": episodes}, args.json)
    print(f"metrics written to {args.json}")
    return summary


if __name__ == "__main__":
    main(tyro.cli(Args))
