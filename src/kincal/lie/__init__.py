"""Lie groups SO(3) and SE(3), and the rpy/quaternion parametrizations; numpy only, batch-first.
See docs/conventions.md."""

from kincal.lie import rotations, se3, so3

__all__ = ["rotations", "se3", "so3"]
