"""Lie groups SO(3) and SE(3), numpy only, batch-first. See docs/conventions.md."""

from kincal.lie import se3, so3

__all__ = ["se3", "so3"]
