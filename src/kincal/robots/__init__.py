"""Built-in robots by name: the catalogue of the model files kincal ships (format in docs/model-format.md).

The files live with the reader, ``kincal/io/builtin_robots/*.yaml``, so that ``kincal.io.load_robot("frida")``
and every file that says ``model: frida`` resolve built-in names without importing this package.
"""

from __future__ import annotations

from kincal.io.models import builtin_names, load_builtin
from kincal.kinematics.model import Robot


def names() -> list[str]:
    """Names of the built-in robots, sorted."""
    return builtin_names()


def load(name: str) -> Robot:
    """The built-in robot ``name`` (e.g. ``"frida"``); DataFormatError lists the names if unknown."""
    return load_builtin(name)
