"""Experiment generators: a true robot in, ``(Dataset, Truth, validation)`` out; one module per kind.

Every generator

- solves the experiment's constraint on the *true* robot (``robot`` argument; make one with
  ``perturb_robot``), so the joint readings are ``true joint value - true offset`` (the model uses
  ``theta = q + offset``), within the joint limits;
- adds noise (``Noise``: encoder noise and backlash along the sample path, tracker noise);
- returns the ground truth (``Truth``) and a validation set: ``{arm: Dataset(kind="pose")}`` of fresh random
  configurations within the limits with the noise-free true tool poses (``T_world_tracker`` = identity);
- is deterministic for a given ``rng`` (numpy Generator or integer seed);
- declares its scenario options next to its code (``@generator(kind, *options)``, ``_common.Option``).

Nuisance quantities (fixture, plate, clamp, tracker, markers, socket) are always in ``Truth.values``; they
are in ``Dataset.known`` only when declared known. Every module of this package not starting with ``_`` is
imported here and its ``__all__`` re-exported, so a new generator is one new module.
"""

from __future__ import annotations

import importlib
import pkgutil

from kincal.simulate.generators._clamped import reachable_pose
from kincal.simulate.generators._common import (REGISTRY, Generator, Option, dataset_spread, random_configurations,
                                                tip_configurations, validation_set, workspace_sample)
from kincal.simulate.generators._tracker import random_markers, random_tracker_pose, random_wrenches


def _import_generators() -> list[str]:
    names = []
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):
            module = importlib.import_module(f"{__name__}.{info.name}")
            for name in module.__all__:
                globals()[name] = getattr(module, name)
            names += module.__all__
    return names


_PUBLIC = _import_generators()
# kind -> generator function, and kind -> its scenario options
GENERATORS = {kind: g.function for kind, g in REGISTRY.items()}
OPTIONS = {kind: g.options for kind, g in REGISTRY.items()}

__all__ = ["GENERATORS", "OPTIONS", "Generator", "Option", "dataset_spread", "random_configurations",
           "random_markers", "random_tracker_pose", "random_wrenches", "reachable_pose", "tip_configurations",
           "validation_set", "workspace_sample", *_PUBLIC]
