"""Where one step's time goes: timers around each phase of the project's env step and of the agent loop.

Wraps the methods a step calls (controller, physics, render submit, the wait for the frame and each
texture's readback, ManiSkill's texture transforms and observation assembly, the reward's segmentation
statistics, the FCN, the wrappers) with timers that nest, and prints each phase's own time per step
(its time minus that of the phases inside it), for the env with the ground-truth box and with the FCN's
box (`EnvConfig(box_source="fcn")`, the agent loop: a Q-network acts on the box), each with the task's
culling on and off (off: every body drawn, as before it; `ActiveVisionFindEnv.cull`), the four envs
stepped in alternating blocks so that they share the machine's load. Resets (new objects every episode,
as `make_env` does) are timed apart. docs/speed.md reads these figures.

    .venv/bin/python baselines/profile_step.py --steps 300
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import torch
import tyro
from mani_skill.sensors.camera import Camera
from mani_skill.utils.structs.render_camera import RenderCamera

import mani_active_vision as mav
import mani_active_vision.tasks.active_vision_find as task
from mani_active_vision import culling
from mani_active_vision.agents.q_network import QNetwork
from mani_active_vision.box_state import BoxState


@dataclass
class Args:
    steps: int = 300
    """timed steps per configuration (after 20 warm-up steps)"""
    image_size: int = 128
    box_sources: tuple[str, ...] = ("ground_truth", "fcn")


class PhaseTimer:
    """Timers that nest: `wrap(owner, name)` times every call of `owner.name` under the phase that is running."""

    def __init__(self):
        self.own = defaultdict(float)  # phase path -> seconds spent in it, not in the phases inside it
        self.stack: list[list] = []  # [path, start, seconds spent in inner phases]
        self.restore: list[tuple] = []

    def wrap(self, owner, name: str, label: str | None = None, method=None):
        original = method or getattr(owner, name)
        label = label or name

        def timed(*args, **kwargs):
            return self.run(label, original, *args, **kwargs)

        self.restore.append((owner, name, owner.__dict__.get(name)))
        setattr(owner, name, timed)

    def run(self, label: str, fn, *args, **kwargs):
        path = (*self.stack[-1][0], label) if self.stack else (label,)
        frame = [path, time.perf_counter(), 0.0]
        self.stack.append(frame)
        try:
            return fn(*args, **kwargs)
        finally:
            self.stack.pop()
            spent = time.perf_counter() - frame[1]
            self.own[path] += spent - frame[2]
            if self.stack:
                self.stack[-1][2] += spent

    def undo(self):
        for owner, name, value in reversed(self.restore):
            if value is None:
                delattr(owner, name)
            else:
                setattr(owner, name, value)
        self.restore.clear()


def instrument(env, timer: PhaseTimer, per_env_only: bool = False):
    """Wrap the phases of one step of `env` (the project's env) and of its reset; `per_env_only`: the classes'
    methods are wrapped already (by the first env's call)."""
    base = env.unwrapped
    timer.wrap(base, "evaluate", "evaluate")
    timer.wrap(base, "_hand_camera_images", "wrist camera")
    timer.wrap(base, "get_obs", "get_obs (ManiSkill's observation assembly)")
    timer.wrap(base, "_get_obs_agent", "proprioception")
    timer.wrap(base, "_get_obs_extra", "target image / extras")
    timer.wrap(base, "get_sensor_params", "camera parameters")
    timer.wrap(base, "get_reward", "reward")
    timer.wrap(base, "_reconfigure", "reconfigure (new objects)")
    timer.wrap(base, "_initialize_episode", "initialize episode")
    for wrapper in _chain(env):
        if isinstance(wrapper, BoxState):
            if wrapper.segmenter is not None:
                timer.wrap(wrapper.segmenter, "predict", "FCN predict")
            timer.wrap(wrapper, "observation", "BoxState")
    if per_env_only:
        return
    # a reset with new objects makes a new scene and agent: wrap their classes, not the instances
    timer.wrap(type(base.agent), "set_action", "controller (IK, drive targets)")
    timer.wrap(type(base.scene), "step", "physics")
    timer.wrap(type(base.scene), "update_render", "update_render (poses to the renderer)")
    timer.wrap(task, "target_stats", "target statistics (mask -> share, box)")
    timer.wrap(culling, "outside_view", "culling: which bodies are out of view")
    timer.wrap(Camera, "capture", "render submit (take_picture)")
    # ManiSkill reads the textures in one call; time each: the first one waits for the frame
    timer.wrap(RenderCamera, "get_picture", "readbacks", method=_timed_get_picture(timer))


def _timed_get_picture(timer: PhaseTimer):
    def get_picture(self, names):
        names = [names] if isinstance(names, str) else names
        out = []
        for i, name in enumerate(names):
            label = f"{'wait for the frame + ' if i == 0 else ''}readback {name}"
            out.append(timer.run(label, lambda n=name: torch.from_numpy(self._render_cameras[0].get_picture(n))[None]))
        return out

    return get_picture


def _chain(env):
    while True:
        yield env
        if not hasattr(env, "env"):
            return
        env = env.env


def profile(args: Args) -> dict:
    """For each (box source, culling) config: own ms per step of each phase, own ms per reset, steps/s (timers
    on). The configs' envs are stepped in alternating blocks of 10 steps, so that they share the machine's load."""
    timer = PhaseTimer()
    runs = {}
    for box_source in args.box_sources:
        for cull in (False, True):
            env = mav.make_env(mav.EnvConfig(start_pose="search", image_size=args.image_size, box_source=box_source))
            env.unwrapped.cull = cull
            timer.own = defaultdict(float)
            instrument(env, timer, per_env_only=bool(runs))
            obs, _ = env.reset(seed=0)
            policy = QNetwork(env.observation_space.shape[-1], num_actions=env.action_space.n)  # untrained: its cost
            runs[box_source, cull] = dict(env=env, obs=obs, policy=policy, rng=np.random.default_rng(0), resets=0)
    for block in range(2 + args.steps // 10):
        for run in runs.values():
            if block == 2:  # warm-up over
                run.update(own=defaultdict(float), resets=0, seconds=0.0)
            timer.own = run.get("own", defaultdict(float))
            began = time.perf_counter()
            for _ in range(10):
                with torch.no_grad():
                    q = timer.run("policy (Q-network)", run["policy"], torch.as_tensor(run["obs"]))
                explore = run["rng"].random() < 0.3
                action = int(run["rng"].integers(run["env"].action_space.n)) if explore else int(q.argmax())
                run["obs"], _, terminated, truncated, _ = timer.run("env.step", run["env"].step, action)
                if terminated or truncated:
                    run["obs"], _ = timer.run("env.reset", run["env"].reset)
                    run["resets"] += 1
            run["seconds"] = run.get("seconds", 0.0) + time.perf_counter() - began
    timer.undo()
    results = {}
    for key, run in runs.items():
        run["env"].close()
        steps = 10 * (args.steps // 10)
        results[key] = (
            {k: 1000 * v / steps for k, v in run["own"].items() if k[0] != "env.reset"},
            {k: 1000 * v / max(run["resets"], 1) for k, v in run["own"].items() if k[0] == "env.reset"},
            steps / run["seconds"],
        )
    return results


def print_tree(times: dict, title: str):
    total = sum(times.values())
    print(f"\n{title}: {total:.2f} ms\n\n| phase | own ms | share |\n|---|---|---|")
    for path in sorted(times):
        print(f"| {'  ' * (len(path) - 1)}{path[-1]} | {times[path]:.2f} | {100 * times[path] / total:.0f}% |")


def main(args: Args):
    torch.set_num_threads(1)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} cores")
    for (box_source, cull), (per_step, per_reset, rate) in profile(args).items():
        what = f"box_source={box_source}, {'culling' if cull else 'no culling (as before)'}"
        print_tree(per_step, f"{what}, {args.image_size}², one step ({rate:.0f} steps/s timed)")
        print_tree(per_reset, f"{what}, one reset with new objects")
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main(tyro.cli(Args))
