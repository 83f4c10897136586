"""How often does a memory agent do what its teacher would, on its own trajectories? The agent acts (greedy) on
held-out episodes; its teacher (the one in its checkpoint's config, built as in training: `search.make_teacher`)
is asked in every state the agent reaches and follows the agent's trajectory. Prints the share of steps on
which they agree, apart where the teacher takes `stay` and where it moves: a learner that leaves success
once in 30 of the teacher's stays breaks a 50-step hold about twice.

    python baselines/teacher_agreement.py --checkpoint agents/weights/search.pt --episodes 50
    python baselines/teacher_agreement.py --checkpoint runs/search_onfcn/seed0/agent.pt --env.object-set unseen

The env is the checkpoint's (each `--env.*` flag given overrides that option).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from mani_active_vision.agents import search
from mani_active_vision.agents.policies import STAY_INDEX, MemoryPolicy
from mani_active_vision.agents.recurrent_network import load_agent
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.evaluation.cli import cli_with_checkpoint_env
from mani_active_vision.evaluation.protocol import EVAL_SEED, eval_seeds
from mani_active_vision.evaluation.rollout import run_episode


@dataclass
class Args:
    env: EnvConfig = field(default_factory=EnvConfig)
    """the env (default: the checkpoint's)"""
    checkpoint: str = "agents/weights/search.pt"
    """a memory agent's checkpoint (agents/search.py)"""
    episodes: int = 50
    """held-out episodes, seeds from `seed`"""
    seed: int = EVAL_SEED
    """seed of the first episode"""


def training_args(config: dict) -> search.Args:
    """The run's `search.Args` from a checkpoint's config (its training env, "trained_env" once shipped)."""
    names = {f.name for f in dataclasses.fields(search.Args)} - {"env"}
    env = EnvConfig.from_dict(config.get("trained_env", config["env"]))
    return search.Args(env=env, **{k: v for k, v in config.items() if k in names})


class Asking:
    """The agent acts; its teacher is asked in the same state and told what the agent did."""

    def __init__(self, agent: MemoryPolicy, teacher):
        self.agent, self.teacher, self.labels, self.actions, self.start = agent, teacher, [], [], True

    def reset(self, obs, info):
        self.agent.reset(obs, info)
        self.start = True

    def act(self, obs, info) -> np.ndarray:
        label = self.teacher.act(obs, info, np.array([self.start]))
        action = self.agent.act(obs, info)
        self.teacher.executed(action)
        self.start = False
        self.labels.append(int(label[0]))
        self.actions.append(int(action[0]))
        return action


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    _, config = load_agent(args.checkpoint)
    if config.get("algo") != "dagger":
        raise ValueError(f"{args.checkpoint!r} was trained with algo={config.get('algo')!r}: it has no teacher to ask")
    env = make_env(args.env)
    try:
        asking = Asking(MemoryPolicy(env, checkpoint=args.checkpoint), search.make_teacher(env, training_args(config)))
        for seed in tqdm(eval_seeds(args.episodes, args.seed), desc="episodes"):
            run_episode(env, asking, seed)
    finally:
        env.close()
    labels, actions = np.array(asking.labels), np.array(asking.actions)
    stays = labels == STAY_INDEX
    result = {
        "steps": len(labels),
        "agree": float((labels == actions).mean()),
        "agree_where_teacher_stays": float((labels == actions)[stays].mean()) if stays.any() else float("nan"),
        "agree_where_teacher_moves": float((labels == actions)[~stays].mean()),
        "teacher_stays": int(stays.sum()),
    }
    print(
        f"{args.checkpoint}: {result['steps']} steps of {args.episodes} episodes; agrees with its teacher on "
        f"{result['agree']:.3f} of them, {result['agree_where_teacher_stays']:.3f} of the teacher's "
        f"{result['teacher_stays']} stays, {result['agree_where_teacher_moves']:.3f} of its moves"
    )
    return result


if __name__ == "__main__":
    main(cli_with_checkpoint_env(Args))
