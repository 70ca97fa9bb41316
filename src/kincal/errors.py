"""Exception hierarchy: every error kincal raises on bad input derives from KincalError."""

from __future__ import annotations


class KincalError(Exception):
    """Base class of all kincal errors."""


class ShapeError(KincalError, ValueError):
    """An array has the wrong shape, dtype or contains non-finite values."""


class ManifoldError(KincalError, ValueError):
    """A value is not on its manifold (non-orthonormal rotation, non-unit axis, ...)."""


class ModelError(KincalError, ValueError):
    """An arm or robot model is inconsistent."""


class DataFormatError(KincalError, ValueError):
    """A file (model, data set, job) is malformed; the message names file, row and field."""


class DegenerateExperimentError(KincalError, ValueError):
    """An experiment cannot determine what was asked of it."""


class ResourceError(KincalError, ValueError):
    """A job needs more memory (or other resources) than the machine offers; refused before it starts."""


class KincalWarning(UserWarning):
    """Input kincal accepts but changed, in one line naming file and field (a rounded rotation it projected)."""
