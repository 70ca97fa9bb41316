"""In-memory experiment data sets: what was measured, for any registered experiment kind.

A ``Dataset`` holds joint readings per arm (model order, SI units) plus the measurements and known
transforms of its kind. What a kind holds is declared by the kind itself (``kincal.experiments.<kind>``
registers a ``kincal.schema.Schema``: number of arms, measured and known entries with their shapes, roles);
``Dataset`` checks any data set against its kind's schema. Files (CSV + YAML manifest) map onto it in
``kincal.io.datasets``; ground truth never lives here (see ``Truth`` in ``kincal.simulate``).

``arms`` lists the arms involved (first is A for two-arm kinds). ``q`` also holds the readings of the arms
carrying them on a tree-structured robot (a torso: ``kincal.kinematics.tree``), as extra entries. Unknown quantities (absent from ``known``)
become parameters of the calibration.

``frames`` (optional, role -> frame name) names the frames of the data set's roles (the kind's
``Schema.roles``). Data sets that name the same frame share one parameter block, e.g. two marker sessions
with the same tracker: ``frames={"tracker": "lab_tracker"}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal.errors import DegenerateExperimentError, ShapeError
from kincal.schema import schema_of

# frame names end up in parameter names and are matched by the globs of free/fixed/priors
_NAME_FORBIDDEN = set("*?[] \t\n")


def frames_problem(kind: str, frames, arms=()) -> tuple[str, str] | None:
    """The first bad entry of a ``frames`` mapping (role -> frame name) as (field, problem), or None.

    ``arms``: the model's arm names; a frame named like an arm would give parameters named like the arm's.
    """
    if not isinstance(frames, Mapping):
        return "frames", f"expected a mapping role -> frame name, found {type(frames).__name__}"
    roles = schema_of(kind).role_keys
    for role, name in frames.items():
        where = f"frames.{role}"
        if role not in roles:
            return where, (f"expected a role of kind '{kind}' ({', '.join(roles) or 'none'}), found {role!r}")
        if not isinstance(name, str) or not name or _NAME_FORBIDDEN & set(name):
            return where, f"expected a non-empty frame name without spaces or *?[], found {name!r}"
        clash = next((a for a in arms if name == a or name.startswith(f"{a}.")), None)
        if clash is not None:
            return where, (f"expected a name that does not start with an arm of the model ('{clash}', whose "
                           f"parameters are named '{clash}.*'), found {name!r}")
    return None


def _ro(a) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


# Entries of ``Dataset.meta`` with one value per sample (the CSV line of each row, its time): subsets select them.
PER_SAMPLE_META = ("lines", "t")


@dataclass(frozen=True, eq=False)
class Dataset:
    """One experiment's data, checked against its kind's schema (``kincal.schema``)."""

    kind: str
    robot: str
    arms: tuple[str, ...]
    q: Mapping[str, np.ndarray]
    measured: Mapping[str, np.ndarray] = field(default_factory=dict)
    known: Mapping[str, np.ndarray] = field(default_factory=dict)
    name: str = "experiment"
    meta: Mapping = field(default_factory=dict)
    frames: Mapping[str, str] = field(default_factory=dict)  # role -> frame name (shared between data sets)

    def __post_init__(self) -> None:
        where = f"data set '{self.name}'"
        schema = schema_of(self.kind, where)
        arms = tuple(self.arms)
        if len(arms) != schema.arms:
            raise ShapeError(f"{where}: kind '{self.kind}' needs {schema.arms} arm(s), got {list(arms)}")
        object.__setattr__(self, "arms", arms)
        q = {}
        for arm in arms:
            if arm not in self.q:
                raise ShapeError(f"{where}: no joint readings for arm '{arm}'")
        for arm in (*arms, *(a for a in self.q if a not in arms)):  # then the readings of the arms carrying them
            qa = np.asarray(self.q[arm], dtype=float)
            if qa.ndim != 2:
                raise ShapeError(f"{where}: joint readings of arm '{arm}' must be (N, n), got shape {qa.shape}")
            bad = np.argwhere(~np.isfinite(qa))
            if len(bad):
                raise ShapeError(f"{where}: arm '{arm}' sample {bad[0][0]} joint {bad[0][1]} is {qa[tuple(bad[0])]}")
            q[arm] = _ro(qa)
        counts = {qa.shape[0] for qa in q.values()}
        if len(counts) != 1:
            raise ShapeError(f"{where}: arms have different sample counts {[(a, q[a].shape[0]) for a in arms]}")
        object.__setattr__(self, "q", MappingProxyType(q))
        object.__setattr__(self, "measured", MappingProxyType({k: _ro(v) for k, v in self.measured.items()}))
        object.__setattr__(self, "known", MappingProxyType({k: _ro(v) for k, v in self.known.items()}))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        bad = frames_problem(self.kind, self.frames)
        if bad:
            raise ShapeError(f"{where}: field {bad[0]}: {bad[1]}")
        object.__setattr__(self, "frames", MappingProxyType(dict(self.frames)))
        schema.check(where, self.measured, self.known, self.size)
        if self.size == 0:
            raise DegenerateExperimentError(f"{where}: contains no samples")

    @property
    def size(self) -> int:
        return next(iter(self.q.values())).shape[0]

    def subset(self, index) -> "Dataset":
        """The samples selected by ``index`` (slice, mask or integer array)."""
        return Dataset(
            self.kind,
            self.robot,
            self.arms,
            {a: v[index] for a, v in self.q.items()},
            {k: v[index] for k, v in self.measured.items()},
            dict(self.known),
            self.name,
            {k: np.asarray(v)[index] if k in PER_SAMPLE_META else v for k, v in self.meta.items()},
            dict(self.frames),
        )
