"""Compatibility only: ``kincal.params`` (being rewritten) imports ``TWIST_COORDS`` from here; it lives in
``kincal.kinematics.twists``. The thesis' identification Jacobian moved to ``kincal.baselines.identification``.
Delete this module once params imports ``kincal.kinematics.TWIST_COORDS``."""

from kincal.kinematics.twists import TWIST_COORDS

__all__ = ["TWIST_COORDS"]
