"""Evaluate a policy on fixed episode seeds: success, success at the end, focus held (the share of steps in
success from the first success on; over the successful episodes), steps to first see the target, steps to
success, SPL, final target fraction, return (`mani_active_vision.metrics`).

    python baselines/evaluate.py --policy servo --episodes 20
    python baselines/evaluate.py --policy explore --then dqn --checkpoint runs/dqn/random_explore_seed0/q_network.pt
    python baselines/evaluate.py --policy explore --then dqn --checkpoint ... --env.box-source fcn --env.object-set unseen
    python baselines/evaluate.py --policy servo --look-over --env.occluders 2 --env.object-set unseen --episodes 50

Episode seeds are `seed, seed+1, ...` (default from 1,000,000: never a training scene). With a DQN
checkpoint the env is the one it was trained in; each `--env.*` flag given overrides that option.
Prints a markdown table and writes the per-episode metrics and their summary as JSON.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch

from mani_active_vision.agents.policies import make_policy, policy_kwargs
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.protocol import EVAL_SEED, eval_seeds, evaluate
from mani_active_vision.evaluation.report import markdown_table
from mani_active_vision.json_io import save_json
from mani_active_vision.metrics import summarize


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env (default: the checkpoint's, if one is given)"""
    policy: str = "servo"
    """random, explore, servo, dqn or memory"""
    then: str = "none"
    """for --policy explore: who takes over once the target is seen (dqn, servo, random, none)"""
    checkpoint: str = ""
    """a DQN checkpoint (q_network.pt), for --policy dqn or --then dqn; the memory agent's (agents/weights/search.pt)
    for --policy memory"""
    epsilon: float = 0.0
    """for a DQN: the share of random actions (ε-greedy; 0 = greedy)"""
    look_over: bool = False
    """for --policy servo or explore, on scenes with --env.occluders: the sweep first looks over the panels
    (policies.LOOK_OVER) and the servo approaches from above (docs/task.md#occluders)"""
    first_turn: int = 0
    """for --policy explore: the orbit first turns back after this many steps (policies.SWEEP_TURN = 14 has seen
    one side of the objects' range); 0 (default): at joint 1's limit"""
    episodes: int = 20
    """evaluation episodes"""
    seed: int = EVAL_SEED
    """seed of the first episode (then +1 each) and of the policy's randomness"""
    reference: bool = True
    """also run the privileged servo on each seed, for SPL's shortest step count"""
    json: str = "outputs/evaluate.json"
    """where the metrics go"""


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    kwargs = policy_kwargs(
        args.policy, args.then, args.checkpoint, args.seed, args.epsilon, args.look_over, args.first_turn
    )
    env = make_env(args.env)
    try:
        policy = make_policy(args.policy, env, **kwargs)
        name = args.policy + (f"→{args.then}" if args.policy == "explore" and args.then != "none" else "")
        episodes = evaluate(env, policy, eval_seeds(args.episodes, args.seed), with_reference=args.reference, desc=name)
    finally:
        env.close()
    summary = summarize(episodes)
    print(markdown_table({name: summary}))
    save_json(
        {
            "policy": name,
            "checkpoint": args.checkpoint,
            "env": dataclasses.asdict(args.env),
            "summary": summary,
            "episodes": episodes,
        },
        args.json,
    )
    print(f"metrics written to {args.json}")
    return summary


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
