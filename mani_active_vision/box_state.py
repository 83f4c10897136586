"""Observation wrapper: the env's observation -> the target's bounding box, the low-dimensional state for control.

`source="ground_truth"` takes the box from the wrist camera's segmentation (needs a `segmentation` obs);
the vision module adds `source="fcn"` (the one-shot segmentation network on rgb + target image).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from mani_active_vision.boxes import mask_to_box

BOX_SOURCES = ("ground_truth",)


class BoxState(gym.ObservationWrapper):
    """Observation = (x, y, w, h) of the target's box, normalised, zeros when not seen; with
    `with_ee_pos`, the camera's commanded position (x, y, z in m) is appended (the paper's "link state").

    Batched ManiSkill envs give a torch tensor (N, 4 or 7); a numpy env (`CPUGymWrapper`) gives (4 or 7,).
    After each observation, `last_mask` is the (N, H, W) bool torch mask the box came from.
    """

    def __init__(self, env: gym.Env, source: str = "ground_truth", with_ee_pos: bool = False):
        super().__init__(env)
        if source not in BOX_SOURCES:
            raise ValueError(f"source={source!r} is not one of: {', '.join(BOX_SOURCES)}")
        if "segmentation" not in env.unwrapped.obs_mode:
            raise ValueError(f"BoxState(source='ground_truth') needs a segmentation obs_mode, got {env.unwrapped.obs_mode!r}")
        self.source = source
        self.with_ee_pos = with_ee_pos
        dim = 7 if with_ee_pos else 4
        # CPUGymWrapper turns a one-env ManiSkill env into a numpy, unbatched one; keep its convention.
        self._numpy = any(type(e).__name__ == "CPUGymWrapper" for e in _wrapper_chain(env))
        shape = (dim,) if self._numpy else (env.unwrapped.num_envs, dim)
        self.observation_space = gym.spaces.Box(-2.0, 2.0, shape=shape, dtype=np.float32)
        self.last_mask = None

    def observation(self, obs):
        seg = torch.as_tensor(obs["sensor_data"]["hand_camera"]["segmentation"])
        if self._numpy:
            seg = seg[None]
        base = self.env.unwrapped
        mask = seg[..., 0] == base.target_seg_id.to(seg.device)[:, None, None]
        self.last_mask = mask
        state = mask_to_box(mask)
        if self.with_ee_pos:
            state = torch.cat([state, base.agent.controller.target_pos.to(state.device)], -1)
        if self._numpy:
            return state[0].cpu().numpy()
        return state


def _wrapper_chain(env):
    while isinstance(env, gym.Wrapper):
        yield env
        env = env.env
    yield env
