"""Perturbations (the paper's "snaps back"): once the policy has focused on the target (first success), the
arm is forced away for a few steps, then the policy acts again until it focuses again."""

from __future__ import annotations

import math

import numpy as np

from mani_active_vision.evaluation.rollout import run_episode


class PushedPolicy:
    """`policy` until its first success (at most `focus_limit` steps), then `push_steps` forced steps of
    `push_direction` (the policy is not asked), then `policy` again until success (at most `recover_limit`
    steps). `stop(trajectory)` ends the episode when the trial is decided; `result` says how it went."""

    def __init__(
        self, env, policy, push_direction: int, push_steps: int, focus_limit: int = 100, recover_limit: int = 50
    ):
        self.policy, self.push_steps, self.focus_limit, self.recover_limit = (
            policy,
            push_steps,
            focus_limit,
            recover_limit,
        )
        self.push = np.full(env.unwrapped.num_envs, push_direction, dtype=np.int64)

    def reset(self, obs, info):
        self.policy.reset(obs, info)
        self.phase, self.steps = "focus", 0
        self.result = {"focused": False, "visible_after_push": False, "recovered": False, "steps_to_recover": math.nan}

    def act(self, obs, info) -> np.ndarray:
        return self.push if self.phase == "push" else self.policy.act(obs, info)

    def stop(self, trajectory) -> bool:
        self.steps += 1
        success = trajectory.success[-1]
        if self.phase == "focus":
            if not success:
                return self.steps >= self.focus_limit
            self.result["focused"], self.phase, self.steps = True, "push", 0
            return self.push_steps == 0 and self._pushed(trajectory)
        if self.phase == "push":
            return self.steps >= self.push_steps and self._pushed(trajectory)
        if success:
            self.result.update(recovered=True, steps_to_recover=float(self.steps))
        return success or self.steps >= self.recover_limit

    def _pushed(self, trajectory) -> bool:
        """The push is over: note what it left; stop if it did not break focus, else let the policy recover."""
        self.result["visible_after_push"] = trajectory.visible[-1]
        if trajectory.success[-1]:
            self.result.update(recovered=True, steps_to_recover=0.0)
            return True
        self.phase, self.steps = "recover", 0
        return False


def perturbation_trial(
    env, policy, seed: int, push_direction: int, push_steps: int, focus_limit: int = 100, recover_limit: int = 50
) -> dict:
    """One trial on `seed`: {"focused", "visible_after_push", "recovered", "steps_to_recover" (NaN if not)}.
    The env needs a step limit of at least focus_limit + push_steps + recover_limit."""
    pushed = PushedPolicy(env, policy, push_direction, push_steps, focus_limit, recover_limit)
    run_episode(env, pushed, seed, stop=pushed.stop)
    return pushed.result
