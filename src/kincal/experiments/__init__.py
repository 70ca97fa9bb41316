"""Experiment kinds: pure residuals with analytic Jacobians, one module per kind.

Each kind module declares everything about its kind: its data (``SCHEMA``, ``kincal.schema``), its residual
quantities (``COMPONENTS``), its residual and Jacobian, its starting values (``initial``, ``start``). Every
module of this package is imported here, which registers its kind (``KINDS``).

``build(datasets, state)`` turns data sets into experiments and the state extras they read (known frames
as given, unknown frames initialized from the nominal arms), plus the names of the unknown extras. Data sets
naming the same frame in ``Dataset.frames`` share it (``sharing``).
"""

from __future__ import annotations

import importlib
import pkgutil
from collections import Counter
from contextlib import ExitStack
from typing import Sequence

import numpy as np

from kincal.data import Dataset
from kincal.errors import DataFormatError
from kincal.experiments.base import KINDS, Experiment, Residual, hung_arms, remembered_kinematics, same_bits
from kincal.kinematics.model import lineage
from kincal.experiments.sharing import frame_kinds, frame_names, frame_values
from kincal.params import State


def _import_kinds() -> None:
    """Import every kind module of this package: defining an Experiment subclass registers its kind (and its
    schema with the data layer), so a new kind is one new module here and nothing else."""
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):  # helpers (base, sharing, handeye) register nothing
            importlib.import_module(f"{__name__}.{info.name}")


_import_kinds()

__all__ = ["Experiment", "KINDS", "Residual", "build", "check_joints", "checked", "frame_kinds",
           "remembered_kinematics", "same_bits"]


def check_joints(ds: Dataset, state: State) -> None:
    """Every arm of the data set, and every arm carrying one (``Robot.mounts``), exists in the model with the same
    number of joints and has readings in the data set."""
    for arm in ds.arms:
        if arm not in state.arms:
            raise DataFormatError(
                f"data set '{ds.name}': arm '{arm}' is not in the model (arms: {', '.join(state.arms)})"
            )
        line = lineage(state.mounts, arm)
        hung = hung_arms(state, line)
        for carrier in (*line, *hung):
            if carrier not in ds.q:
                why = f"which carries arm '{arm}'" if carrier in line else f"whose weight loads the joints carrying arm '{arm}'"
                raise DataFormatError(f"data set '{ds.name}': field q[{carrier}]: no readings of arm '{carrier}', "
                                      f"{why}; expected its joint readings in the data set")
            a = state.arms[carrier]
            n = ds.q[carrier].shape[1]
            if n != a.dof:
                raise DataFormatError(
                    f"data set '{ds.name}': field q[{carrier}] has {n} joints per sample, expected {a.dof} "
                    f"({', '.join(a.joint_names)}) for arm '{carrier}' of the model"
                )


def build(datasets: Sequence[Dataset], state: State, keep: ExitStack | None = None
          ) -> tuple[list[Experiment], dict[str, object], list[str]]:
    """(experiments, extras, names of unknown extras). Frame names are the role (``fixture``) when only one
    data set has that role, else ``<data set>.<role>``, unless ``Dataset.frames`` names them; data sets naming
    the same frame share it (``kincal.experiments.sharing``). ``keep``: the experiments' kinematics are
    remembered (``remembered_kinematics``) until it closes, from the initial guesses of unknown frames on (forward
    kinematics at ``state``, which a solve from there reuses)."""
    names = [d.name for d in datasets]
    if len(set(names)) < len(names):
        dup = [n for n, c in Counter(names).items() if c > 1]
        raise DataFormatError(f"data set names must be unique; repeated: {', '.join(dup)}")
    experiments = []
    for ds, frames in zip(datasets, frame_names(datasets, tuple(state.arms))):
        check_joints(ds, state)
        experiments.append(checked(ds, frames))
    if keep is not None:
        keep.enter_context(remembered_kinematics(experiments))
    extras, unknown = frame_values(experiments, state)
    return experiments, extras, unknown


def checked(ds: Dataset, frames) -> Experiment:
    """The experiment of ``ds`` with its frames' names, after what its measured and known values must pass:
    finite, and the kind's own ``check``."""
    _check_finite(ds)
    exp = KINDS[ds.kind](ds, frames)
    exp.check()
    return exp


def _check_finite(ds: Dataset) -> None:
    for group, store in (("measured", ds.measured), ("known", ds.known)):
        for key, value in store.items():
            v = np.asarray(value, dtype=float)
            if np.logical_and.reduce(np.isfinite(v), axis=None):  # ``.all()`` without its wrapper
                continue
            bad = np.argwhere(~np.isfinite(v))
            where = f"sample {bad[0][0]} " if group == "measured" else ""
            raise DataFormatError(
                f"data set '{ds.name}': {where}field {group}['{key}'] at index {tuple(int(i) for i in bad[0])} "
                f"is {v[tuple(bad[0])]}, expected a finite number"
            )
