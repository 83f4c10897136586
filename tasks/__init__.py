"""ManiSkill tasks of mani-active-vision (installed as `mani_active_vision.tasks`)."""
