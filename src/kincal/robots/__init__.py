"""Built-in robot models, shipped as model files (``robots/*.yaml``, format in docs/model-format.md)."""

from __future__ import annotations

from importlib import resources

from kincal.kinematics.model import Robot


def names() -> list[str]:
    """Names of the built-in robots, sorted."""
    return sorted(f.name[:-5] for f in resources.files(__name__).iterdir() if f.name.endswith(".yaml"))


def load(name: str) -> Robot:
    """The built-in robot ``name`` (e.g. ``"frida"``); DataFormatError lists the names if unknown."""
    from kincal.errors import DataFormatError
    from kincal.io.models import parse_robot

    if name not in names():
        raise DataFormatError(f"unknown built-in robot {name!r}; built-in robots: {', '.join(names())}")
    res = resources.files(__name__) / f"{name}.yaml"
    return parse_robot(res.read_text(encoding="utf-8"), f"{name}.yaml (built-in)")
