"""mani-active-vision: a KUKA iiwa with a wrist camera learns to find an object seen once, and zoom in.

`import mani_active_vision` registers the robot `iiwa_wristcam` and the task `ActiveVisionFind-v0`;
`make_env(EnvConfig(...))` builds the project's wrapped env (docs/design.md §2).
"""

from mani_active_vision.boxes import mask_to_box
from mani_active_vision.directions import DIRECTIONS, DiscreteDirections
from mani_active_vision.envs import EnvConfig, make_env
from mani_active_vision.robots.iiwa import IiwaWristCam  # registers "iiwa_wristcam"
from mani_active_vision.tasks.active_vision_find import ActiveVisionFindEnv  # registers "ActiveVisionFind-v0"
from mani_active_vision.vec_env import make_vec_env

__all__ = [
    "ActiveVisionFindEnv",
    "IiwaWristCam",
    "DIRECTIONS",
    "DiscreteDirections",
    "EnvConfig",
    "make_env",
    "mask_to_box",
    "make_vec_env",
]
