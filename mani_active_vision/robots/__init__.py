"""Robots (ManiSkill agents): the iiwa with its wrist camera and its controller."""
