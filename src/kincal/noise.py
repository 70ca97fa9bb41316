"""Noise: one concept for simulation, calibration, jobs and data set manifests.

Every residual component an experiment kind declares has a ``Quantity``: what it measures and its SI unit.
A ``Noise`` states one standard deviation per quantity (``position`` m, ``orientation`` rad, and any other a
kind declares, such as ``pixel``), plus the joint encoders' (``joint`` rad) and their backlash (``backlash``
rad, a dead band that simulation draws and calibration does not model).

``None`` means *not stated*. Simulation adds no noise there; calibration refuses to whiten a residual
component whose quantity has no stated noise, so a new kind of measurement is never weighted by a guess.
Files spell a standard deviation ``<quantity>_<unit>`` (``position_mm``, ``orientation_deg``, ``joint_deg``,
``pixel_px``); Python spells it ``Noise(position=..., joint=...)`` in SI units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

from kincal.errors import ModelError


@dataclass(frozen=True)
class Quantity:
    """What a residual component measures: ``name`` (the noise key), SI ``unit``, and whether it is a length
    (scales with the robot: the scale test reads only length components)."""

    name: str
    unit: str
    length: bool = False


POSITION = Quantity("position", "m", length=True)
ORIENTATION = Quantity("orientation", "rad")
PIXEL = Quantity("pixel", "px")

QUANTITIES = {q.name: q for q in (POSITION, ORIENTATION, PIXEL)}
_NAMED = ("position", "orientation", "joint", "backlash")


@dataclass(frozen=True)
class Noise:
    """Standard deviations in SI units; ``None``: not stated. ``other``: further quantities by name."""

    position: float | None = None
    orientation: float | None = None
    joint: float | None = None
    backlash: float | None = None
    other: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, value in self.items(stated_only=False):
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ModelError(f"noise {key}: expected a finite number >= 0, found {value!r}")
        clash = set(self.other) & set(_NAMED)
        if clash:
            raise ModelError(f"noise: {sorted(clash)} are named fields, not 'other' quantities")
        object.__setattr__(self, "other", MappingProxyType(dict(self.other)))

    def items(self, stated_only: bool = True):
        """(quantity name, sigma) pairs: the named fields, then ``other``."""
        pairs = [(k, getattr(self, k)) for k in _NAMED] + list(self.other.items())
        return [(k, v) for k, v in pairs if v is not None or not stated_only]

    def sigma(self, quantity: Quantity | str) -> float | None:
        """The stated standard deviation of ``quantity`` (SI), or None."""
        name = quantity if isinstance(quantity, str) else quantity.name
        return getattr(self, name) if name in _NAMED else self.other.get(name)

    def joint_sigma(self) -> float:
        """Encoder noise, 0 when not stated."""
        return self.joint or 0.0

    def over(self, base: "Noise") -> "Noise":
        """This noise where stated, ``base`` elsewhere (job noise over a data set's own)."""
        named = {k: getattr(self, k) if getattr(self, k) is not None else getattr(base, k) for k in _NAMED}
        return Noise(**named, other={**base.other, **self.other})

    def as_si(self) -> dict[str, float]:
        """File keys in SI units, stated values only: ``{"position_m": ..., "joint_rad": ...}``."""
        units = {"joint": "rad", "backlash": "rad", **{q.name: q.unit for q in QUANTITIES.values()}}
        return {f"{k}_{units.get(k, 'si')}": float(v) for k, v in self.items()}

    @staticmethod
    def from_si(keys: Mapping[str, float]) -> "Noise":
        """Inverse of ``as_si``."""
        values = {k.rpartition("_")[0]: float(v) for k, v in keys.items()}
        named = {k: values.pop(k) for k in _NAMED if k in values}
        return Noise(**named, other=values)


# What ``calibrate`` assumes when no noise is given: 10 micrometres, 10 microradians, 10 microradians.
DEFAULT = Noise(position=1e-5, orientation=1e-5, joint=1e-5)
NONE = Noise()


def effective(explicit: Noise | None, stated: Mapping[str, float] | None) -> Noise:
    """The one noise rule (API, job files, CLI): per quantity, the ``explicit`` noise (a ``calibrate`` argument,
    a job file's ``noise:``) where it states one, else the data set's own stated noise (``stated``: SI keys, as
    ``Dataset.meta["noise"]`` holds a manifest's or a generator's), else ``DEFAULT``. One ``Noise`` built from
    the three: ``explicit.over(stated).over(DEFAULT)`` without the one between (valid, its parts being so)."""
    layers = (explicit or NONE, Noise.from_si(stated or {}), DEFAULT)
    named = {k: next((v for v in (getattr(n, k) for n in layers) if v is not None), None) for k in _NAMED}
    return Noise(**named, other={**DEFAULT.other, **layers[1].other, **layers[0].other})

__all__ = ["DEFAULT", "NONE", "Noise", "ORIENTATION", "PIXEL", "POSITION", "Quantity", "effective"]
