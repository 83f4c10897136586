"""Record rollouts of ActiveVisionFind-v0 to Rerun `.rrd` files that anyone can replay offline.

    from mani_active_vision.envs import EnvConfig, make_env
    from mani_active_vision.recording import RerunRecorder

    with RerunRecorder(make_env(EnvConfig(box_source="fcn")), "recordings/run.rrd") as env:
        ...  # reset and step it with any policy; closing (also on errors, Ctrl-C) writes the footer

    rerun recordings/run.rrd                                     # the viewer
    python baselines/screenshots.py recordings/run.rrd --steps 20 60   # PNGs without a screen

Modules, one job each: `blueprint` (the viewer's layout, stored in the file), `log` (functions that log
what they are given), `recorder` (the wrappers: `RerunRecorder` for one ManiSkill env, batched or not,
and `RerunVectorRecorder` for a gymnasium vector env), `screenshots` (a headless viewer client).
What a file holds: recordings/README.md.
"""

from mani_active_vision.recording.blueprint import blueprint
from mani_active_vision.recording.recorder import IMAGE_FORMATS, RerunRecorder, RerunVectorRecorder, check_writable

__all__ = ["IMAGE_FORMATS", "RerunRecorder", "RerunVectorRecorder", "blueprint", "check_writable"]
