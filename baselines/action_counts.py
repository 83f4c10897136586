"""Which actions a DQN checkpoint takes once the exploration has handed over: counts by name over a few
evaluation episodes (does an agent with `stay` hold by staying, or by oscillating?).

    python baselines/action_counts.py --checkpoint runs/seeds/stay/hold/seed0/q_network.pt --episodes 5
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import torch

from mani_active_vision.agents.policies import make_policy
from mani_active_vision.directions import action_names
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.protocol import EVAL_SEED, eval_seeds
from mani_active_vision.evaluation.rollout import run_episode


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env (default: the checkpoint's)"""
    checkpoint: str = ""
    """a DQN checkpoint trained with exploration"""
    episodes: int = 5
    """evaluation episodes (seeds from `seed`)"""
    seed: int = EVAL_SEED


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    env = make_env(args.env)
    try:
        policy = make_policy("explore", env, then="dqn", checkpoint=args.checkpoint, seed=args.seed)
        names, learner, counts = action_names(args.env.stay_action), policy.then, collections.Counter()
        learner_act = learner.act

        def counted(obs, info):
            action = learner_act(obs, info)
            counts[names[int(action[0])]] += 1
            return action

        learner.act = counted
        for seed in eval_seeds(args.episodes, args.seed):
            trajectory = run_episode(env, policy, seed)
            print(f"episode {seed}: success {any(trajectory.success)}, at the end {trajectory.success[-1]}")
    finally:
        env.close()
    print("the DQN's actions:", dict(counts.most_common()))
    return dict(counts)


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
