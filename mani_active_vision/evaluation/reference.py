"""The privileged reference behind SPL: the scripted servo that knows from the start which way the target
lies and orbits that way first. Its steps to success on a seed are the shortest path we know of (at the full
step: with the env's fine moves too, it keeps to the six directions, so that SPL stays comparable across action
sets)."""

from __future__ import annotations

import math

from mani_active_vision.agents.policies import ServoPolicy
from mani_active_vision.evaluation.rollout import run_episode
from mani_active_vision.metrics import first_index


def toward_target_sweep(env) -> str:
    """The orbit direction ("left" = counter-clockwise seen from above) that faces the target soonest:
    privileged (reads the target's position), for the reference only."""
    base = env.unwrapped
    target = base.target.pose.p[0]
    camera = base.agent.controller.target_pos[0]
    turn = math.atan2(float(target[1]), float(target[0])) - math.atan2(float(camera[1]), float(camera[0]))
    turn = (turn + math.pi) % (2 * math.pi) - math.pi
    return "left" if turn > 0 else "right"


def reference_steps(env, seed: int) -> float:
    """Steps to the first success of the privileged servo on this seed (NaN if it does not succeed)."""
    env.reset(seed=seed)
    servo = ServoPolicy(env, first_sweep=toward_target_sweep(env), fine=False)  # the full step, whatever the env offers
    trajectory = run_episode(env, servo, seed, stop=lambda t: t.success[-1])
    return first_index(trajectory.success)
