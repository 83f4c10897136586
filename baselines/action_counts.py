"""Which actions a DQN checkpoint takes once the exploration has handed over: counts by name over a few
evaluation episodes (does an agent with `stay` hold by staying, or by oscillating?), and which episodes end
in a cycle (the same few actions over and over: a greedy agent on a memoryless state that returns to a state
repeats itself to the end), and where each episode ended (the target's share of the image and its centre's
offset: how far from success a `stay` or a cycle sits).

    python baselines/action_counts.py --checkpoint runs/seeds/stay/hold/seed0/q_network.pt --episodes 5
    python baselines/action_counts.py --checkpoint agents/weights/dqn.pt --episodes 50
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
from mani_active_vision.metrics import first_env


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env (default: the checkpoint's)"""
    checkpoint: str = ""
    """a DQN checkpoint trained with exploration"""
    episodes: int = 5
    """evaluation episodes (seeds from `seed`)"""
    seed: int = EVAL_SEED


CYCLE_STEPS = 20
"""an episode ends in a cycle when its last this many actions repeat with a period of at most MAX_PERIOD"""
MAX_PERIOD = 4


def ending_cycle(actions: list[int]) -> int | None:
    """The period (1-4) with which the last CYCLE_STEPS actions repeat, or None (also for shorter episodes)."""
    tail = actions[-CYCLE_STEPS:]
    if len(tail) < CYCLE_STEPS:
        return None
    return next((p for p in range(1, MAX_PERIOD + 1) if tail[p:] == tail[:-p]), None)


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    env = make_env(args.env)
    try:
        policy = make_policy("explore", env, then="dqn", checkpoint=args.checkpoint, seed=args.seed)
        names = action_names(args.env.stay_action, args.env.fine_step_size > 0)
        learner, counts = policy.then, collections.Counter()
        learner_act, episode_actions = learner.act, []
        cycles = collections.Counter()  # (succeeded, ends in a cycle) -> episodes

        def counted(obs, info):
            action = learner_act(obs, info)
            counts[names[int(action[0])]] += 1
            episode_actions.append(int(action[0]))
            return action

        learner.act = counted
        last_info = {}
        for seed in eval_seeds(args.episodes, args.seed):
            episode_actions.clear()
            trajectory = run_episode(env, policy, seed, on_step=lambda obs, info: last_info.update(info=info))
            period = ending_cycle(episode_actions)
            cycles[any(trajectory.success), period is not None] += 1
            cycle = f", ends in a cycle of {'-'.join(names[a] for a in episode_actions[-period:])}" if period else ""
            share, offset = (first_env(last_info["info"], k) for k in ("target_fraction", "target_center_offset"))
            print(
                f"episode {seed}: success {any(trajectory.success)}, at the end {trajectory.success[-1]} (share "
                f"{share:.3f}, centre offset {offset:.3f}){cycle}"
            )
    finally:
        env.close()
    print("the DQN's actions:", dict(counts.most_common()))
    for succeeded in (False, True):
        total = cycles[succeeded, True] + cycles[succeeded, False]
        print(
            f"{'successful' if succeeded else 'unsuccessful'} episodes ending in a cycle: {cycles[succeeded, True]} of {total}"
        )
    return dict(counts)


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
