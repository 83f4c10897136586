"""The project's one episode loop: a policy acts in an env from a seeded reset until the episode ends.

Evaluation, recording and perturbations all run episodes through `run_episode`. Ctrl-C stops it after the
step in progress (raising KeyboardInterrupt), so that a recorder around the env logs the last step whole
and closes a valid file; a second Ctrl-C interrupts at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable

import torch

from mani_active_vision.metrics import Trajectory


def run_episode(
    env,
    policy,
    seed: int | None,
    max_steps: int | None = None,
    stop: Callable[[Trajectory], bool] | None = None,
    on_step: Callable[[object, dict], None] | None = None,
) -> Trajectory:
    """One episode of `policy` on env 0 from `env.reset(seed=seed)`, until it terminates or is truncated,
    after `max_steps` steps, or when `stop(trajectory)` says so (checked after every step). `on_step(obs,
    info)` sees every observation, the reset's included (e.g. to keep frames)."""
    obs, info = env.reset(seed=seed)
    policy.reset(obs, info)
    trajectory = Trajectory()
    trajectory.start(info)
    if on_step is not None:
        on_step(obs, info)
    steps = 0
    with stop_on_ctrl_c() as stop_requested:
        while max_steps is None or steps < max_steps:
            if stop_requested():
                raise KeyboardInterrupt(f"stopped by Ctrl-C at step {steps} of the episode with seed {seed}")
            obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
            trajectory.append(reward, info)
            if on_step is not None:
                on_step(obs, info)
            steps += 1
            if bool(torch.as_tensor(terminated | truncated).reshape(-1)[0]) or (stop is not None and stop(trajectory)):
                break
    return trajectory


@contextlib.contextmanager
def stop_on_ctrl_c():
    """Turn the first SIGINT into a request that loops check between steps; yields that check. The default
    KeyboardInterrupt is raised wherever Python happens to be (and one raised inside a `__del__` or a
    callback is printed and swallowed, so a run could go on after Ctrl-C). Nested uses share the outer
    request. Only the main thread can handle signals: elsewhere the check is always False."""
    current = signal.getsignal(signal.SIGINT)
    if hasattr(current, "stop_requested"):
        yield current.stop_requested
        return
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    requested = []

    def handler(signum, frame):
        if requested:  # the second Ctrl-C: at once
            raise KeyboardInterrupt
        requested.append(signum)

    handler.stop_requested = lambda: bool(requested)
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield handler.stop_requested
    finally:
        signal.signal(signal.SIGINT, previous)
