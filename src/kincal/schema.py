"""What a data set of each experiment kind holds: a ``Schema`` per kind, declared by the kind, checked here.

An experiment kind (``kincal.experiments.<kind>``) declares and registers its schema: how many arms, the
measured entries (per sample, with their CSV columns), the known entries (whole values, with their manifest
form) and its roles, the frames it names (role -> known entry, which side of the measurement loop the frame
sits on, and the kind of parameter it becomes when unknown). ``Dataset`` (``kincal.data``) and the data set
files (``kincal.io.datasets``) read only these declarations: no table per kind lives outside the kind.

Shapes are per sample for measured entries and whole values for known ones. A dimension given as a name
(``"m"`` markers, ``"K"`` fixtures) is a size the data choose; every entry using the same name must agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal.errors import ShapeError

# unit kinds: how the numbers of an entry scale with a file's units (a pose's translation is always a length)
LENGTH, ANGLE, NONE = "length", "angle", "none"
UNITS = (LENGTH, ANGLE, NONE)
# forms: how an entry is written in files (``kincal.io.datasets``) and what shape it has
FORM_SHAPES = {
    "pose": (4, 4),  # CSV: <prefix>.x .. <prefix>.qz (quaternion w, x, y, z); manifest: a pose block
    "poses": ("K", 4, 4),  # manifest: a list of pose blocks
    "points": ("m", 3),  # CSV: <prefix>1.x, <prefix>1.y, ... ; manifest: a list of [x, y, z]
    "vector": None,  # CSV: the named columns; manifest: a list of numbers (shape from ``size``)
    "scalar": (),  # manifest: a number
    "plane": (4,),  # manifest: [nx, ny, nz, d] with a unit normal
    "index": (),  # CSV: one integer column, an index into the first dimension of ``bound``
    # a pose's 6x6 covariance, components (position, orientation); CSV: <prefix>.<a>.<b> for the 21 entries a <= b
    # of x y z rx ry rz, position in the file's length unit, orientation in its angle unit
    "covariance": (6, 6),
}
# which side of the measurement loop a role's frame sits on
WORLD, TOOL, BETWEEN = "world", "tool", "between"
# the kind of parameter an unknown frame becomes (its value: 4x4 pose, (3,) point, (m, 3) points, plane [n, d])
PARAMETERS = ("pose", "point", "points", "plane")


@dataclass(frozen=True)
class Field:
    """One measured (per sample) or known (whole value) entry of a data set.

    ``columns``: CSV columns of a measured entry: the prefix of a ``pose`` or ``points`` entry (``tool``,
    ``m``), the names of a ``vector``'s columns, the name of an ``index`` column. ``bound``: for an
    ``index``, the known entry it indexes. ``names``: a dimension name for ``pose``/``points`` sizes chosen
    by the data (defaults ``K``/``m``).
    """

    key: str
    form: str
    unit: str = NONE
    required: bool = True
    columns: tuple[str, ...] = ()
    size: int | str | None = None  # vector length, or the name of a data-chosen count (points, poses)
    bound: str | None = None
    doc: str = ""

    def __post_init__(self) -> None:
        if self.form not in FORM_SHAPES:
            raise ValueError(f"field {self.key!r}: form {self.form!r} is not one of {', '.join(FORM_SHAPES)}")
        if self.unit not in UNITS:
            raise ValueError(f"field {self.key!r}: unit kind {self.unit!r} is not one of {', '.join(UNITS)}")
        if self.form == "vector" and not isinstance(self.size, int):
            raise ValueError(f"field {self.key!r}: a vector needs an integer size")
        if self.form == "index" and not self.bound:
            raise ValueError(f"field {self.key!r}: an index needs the known entry it indexes (bound)")

    @property
    def shape(self) -> tuple:
        """Shape of the value (per sample for measured entries); names stand for data-chosen sizes."""
        if self.form == "vector":
            return (self.size,)
        base = FORM_SHAPES[self.form]
        if self.size is not None and self.form in ("points", "poses"):
            return (self.size,) + base[1:]
        return base


@dataclass(frozen=True)
class Role:
    """A frame a kind names: its entry in ``known``, the side of the loop it sits on, its parameter kind."""

    name: str
    key: str
    side: str
    parameter: str

    def __post_init__(self) -> None:
        if self.side not in (WORLD, TOOL, BETWEEN):
            raise ValueError(f"role {self.name!r}: side {self.side!r} is not world, tool or between")
        if self.parameter not in PARAMETERS:
            raise ValueError(f"role {self.name!r}: parameter kind {self.parameter!r} is not one of {PARAMETERS}")


@dataclass(frozen=True)
class Schema:
    """The data of one experiment kind."""

    kind: str
    arms: int
    measured: tuple[Field, ...] = ()
    known: tuple[Field, ...] = ()
    roles: tuple[Role, ...] = ()
    doc: str = ""

    def __post_init__(self) -> None:
        keys = {f.key for f in self.known}
        for r in self.roles:
            if r.key not in keys:
                raise ValueError(f"kind {self.kind!r}: role {r.name!r} names {r.key!r}, which is no known entry")

    @property
    def role_keys(self) -> Mapping[str, str]:
        """role -> its entry in ``known``."""
        return MappingProxyType({r.name: r.key for r in self.roles})

    def role(self, name: str) -> Role:
        return next(r for r in self.roles if r.name == name)

    def field(self, key: str) -> Field:
        return next(f for f in self.measured + self.known if f.key == key)

    def side_key(self, *sides: str) -> str | None:
        """The known entry of the (first) role on one of ``sides``, or None."""
        return next((r.key for r in self.roles if r.side in sides), None)

    def check(self, where: str, measured: Mapping, known: Mapping, n: int) -> None:
        """Raise ShapeError unless ``measured``/``known`` hold this kind's entries with their shapes."""
        for group, fields, store in (("measured", self.measured, measured), ("known", self.known, known)):
            allowed = [f.key for f in fields]
            for f in fields:
                if f.required and f.key not in store:
                    raise ShapeError(f"{where}: kind '{self.kind}' needs {group} '{f.key}'")
            for k in store:
                if k not in allowed:
                    raise ShapeError(f"{where}: unexpected {group} entry '{k}' for kind '{self.kind}'; "
                                     f"allowed: {', '.join(allowed) or 'none'}")
        self._sizes(where, measured, known, n)

    def sizes(self, measured: Mapping, known: Mapping, n: int) -> dict[str, int]:
        """The data-chosen sizes (``{"m": 3}``) of checked data."""
        return {k: v[0] for k, v in self._sizes(f"kind '{self.kind}'", measured, known, n).items()}

    def _sizes(self, where, measured, known, n) -> dict[str, tuple[int, str]]:
        sizes: dict[str, tuple[int, str]] = {}
        for group, fields, store, lead in (("measured", self.measured, measured, (n,)),
                                           ("known", self.known, known, ())):
            for f in fields:
                if f.key in store:
                    _check_shape(where, group, f, np.shape(store[f.key]), lead, sizes)
        return sizes


def _check_shape(where: str, group: str, f: Field, shape: tuple, lead: tuple, sizes: dict) -> None:
    if shape[: len(lead)] != lead:
        raise ShapeError(f"{where}: {group} '{f.key}' has {shape[:1]} samples, joint readings have {lead[0]}")
    got, want = shape[len(lead):], f.shape
    if len(got) != len(want) or any(isinstance(w, int) and g != w for g, w in zip(got, want)):
        shown = tuple("N",) + want if lead else want
        raise ShapeError(f"{where}: {group} '{f.key}' must have shape {_show(shown)}, got {shape}")
    for g, w in zip(got, want):
        if isinstance(w, str):
            first, source = sizes.setdefault(w, (g, f.key))
            if first != g:
                raise ShapeError(f"{where}: {group} '{f.key}' has {w} = {g}, '{source}' has {w} = {first}")


def _show(shape: tuple) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


_REGISTRY: dict[str, Schema] = {}
SCHEMAS: Mapping[str, Schema] = MappingProxyType(_REGISTRY)


def register(schema: Schema) -> Schema:
    """Make a kind known to ``Dataset`` and the files; a kind registers once."""
    old = _REGISTRY.get(schema.kind)
    if old is not None and old != schema:
        raise ValueError(f"experiment kind {schema.kind!r} is registered twice with different schemas")
    _REGISTRY[schema.kind] = schema
    return schema


def schema_of(kind: str, where: str = "data set") -> Schema:
    """The registered schema of ``kind``; ShapeError naming the known kinds otherwise."""
    if kind not in _REGISTRY:
        raise ShapeError(f"{where}: unknown kind {kind!r}; kinds: {', '.join(_REGISTRY)}")
    return _REGISTRY[kind]


def covariance_problem(cov: np.ndarray) -> tuple[int, str] | None:
    """The first row of covariances ``cov`` (N, k, k) that is not symmetric positive definite, as
    (row, what was found), or None."""
    cov = np.asarray(cov, dtype=float)
    bad = np.flatnonzero(~np.isfinite(cov).all(axis=(1, 2)))
    if bad.size:
        return int(bad[0]), "non-finite entries"
    asym = np.abs(cov - np.swapaxes(cov, -1, -2)).max(axis=(1, 2))
    bad = np.flatnonzero(asym > 1e-9 * np.abs(cov).max(axis=(1, 2)))
    if bad.size:
        return int(bad[0]), f"an asymmetric matrix (|C - C^T| up to {asym[bad[0]]:.3g})"
    eig = np.linalg.eigvalsh(cov)[:, 0]
    bad = np.flatnonzero(eig <= 0)
    if bad.size:
        return int(bad[0]), f"a matrix that is not positive definite (smallest eigenvalue {eig[bad[0]]:.3g})"
    return None
