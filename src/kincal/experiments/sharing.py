"""Naming the frames of experiments and sharing them between data sets.

A frame (tracker, fixture, plate, clamp, markers, socket, plane) is a state extra. Its name is the role
(``tracker``) when only one data set has that role, else ``<data set>.<role>``, unless the data set's
``frames`` names it. Data sets naming the same frame share one parameter block (one tracker seen in two
sessions, one clamp in two dual-arm data sets): a frame known in any of them is known in all (the values must
agree), and an unknown one starts from the first data set's initial guess.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from kincal.data import Dataset, frames_problem
from kincal.errors import DataFormatError
from kincal._memo import remember
from kincal.params import FRAME_KINDS, State
from kincal.params.layout import on_clear
from kincal.schema import schema_of

KNOWN_ATOL = 1e-9  # two data sets giving a shared frame as known must agree to this (m, and rotation entries)


def frame_names(datasets: Sequence[Dataset], arms: Sequence[str]) -> list[dict[str, str]]:
    """Per data set, role -> frame name. A name given in ``frames`` must be valid, and a frame may only be
    shared between data sets in which it plays the same role."""
    # every data set with the role counts, named or not, so naming one frame never renames another's
    roles = [tuple(schema_of(d.kind).role_keys) for d in datasets]
    count: dict[str, int] = {}
    for r in (r for rs in roles for r in rs):
        count[r] = count.get(r, 0) + 1
    owner: dict[str, tuple[str, str]] = {}  # frame name -> (first data set, role)
    out = []
    for ds, rs in zip(datasets, roles):
        bad = frames_problem(ds.kind, ds.frames, arms) if ds.frames else None  # none named: nothing to check
        if bad:
            raise DataFormatError(f"data set '{ds.name}': field {bad[0]}: {bad[1]}")
        names = {r: ds.frames.get(r) or (r if count[r] == 1 else f"{ds.name}.{r}") for r in rs}
        for role, name in names.items():
            first, first_role = owner.setdefault(name, (ds.name, role))
            if first_role != role:
                # blame the data set that named the frame (the other one may just have its default name)
                here = (ds.name, role, first, first_role)
                mine, r, theirs, r2 = here if role in ds.frames else (first, first_role, ds.name, role)
                raise DataFormatError(
                    f"data set '{mine}': field frames.{r}: frame '{name}' is the {r2} of data set '{theirs}'; "
                    f"a {r} cannot share a frame with a {r2} (only frames of the same role can be shared)"
                )
        out.append(names)
    return out


def frame_values(experiments, state: State) -> tuple[dict[str, object], list[str]]:
    """(extras, names of the unknown ones): known values as given, unknown ones initialized from the nominal arms."""
    _check_shapes(experiments)
    values = _known(experiments)  # raw arrays by frame name; each kind makes its value from them
    extras, unknown = {}, []
    for exp in experiments:
        given = {r: values[n] for r, n in exp.frames.items() if n in values}
        guesses = exp.initial(state, given)
        for role, value in {**given, **guesses}.items():
            name = exp.frames[role]
            if role in guesses:
                values[name] = value
                unknown.append(name)
            if name not in extras:
                extras[name] = as_extra(exp, role, value)
    return extras, unknown


def role_kind(exp, role: str):
    """The parameter kind (``kincal.params.kinds``) of an experiment role's frame, from the kind's schema;
    remembered per schema object (held with the entry: its id is not reused meanwhile) and role, schemas being
    immutable."""
    schema = exp.SCHEMA
    hit = _ROLE_KINDS.get((id(schema), role))
    if hit is None or hit[0] is not schema:
        hit = remember(_ROLE_KINDS, (id(schema), role), (schema, FRAME_KINDS[schema.role(role).parameter]),
                       ROLE_KIND_ENTRIES)
    return hit[1]


# role_kind's memory: (id(schema), role) -> (the schema, the role's parameter kind), oldest first
_ROLE_KINDS: dict[tuple, tuple] = {}
ROLE_KIND_ENTRIES = 64


@on_clear
def clear_role_kinds() -> None:
    """Forget what ``role_kind`` remembered (``kincal.params.clear_caches`` runs this)."""
    _ROLE_KINDS.clear()


def as_extra(exp, role: str, value):
    """A frame's value as the state holds it (a plane as ``Plane``): made by the role's parameter kind."""
    return role_kind(exp, role).from_raw(value)


def frame_kinds(experiments) -> dict[str, object]:
    """Frame name -> its parameter kind."""
    return {name: role_kind(exp, role) for exp in experiments for role, name in exp.frames.items()}


def _check_shapes(experiments) -> None:
    """Known values have the shape their data need, and data sets sharing a frame need the same shape (for
    example the same number of markers)."""
    uses: dict[str, int] = {}
    for name in (n for exp in experiments for n in exp.frames.values()):
        uses[name] = uses.get(name, 0) + 1
    first: dict[str, tuple[tuple, str]] = {}
    for exp in experiments:
        shapes = None
        for role, name in exp.frames.items():
            key = exp.ROLES[role]
            if uses[name] == 1 and key not in exp.dataset.known:  # no value to check, no other data set to agree
                continue
            shapes = exp.frame_shapes() if shapes is None else shapes
            shape = shapes[role]
            if key in exp.dataset.known and np.shape(exp.dataset.known[key]) != shape:
                raise DataFormatError(f"data set '{exp.name}': field known['{key}'] has shape "
                                      f"{np.shape(exp.dataset.known[key])}, expected {shape}")
            s, other = first.setdefault(name, (shape, exp.name))
            if s != shape:
                raise DataFormatError(
                    f"data sets '{other}' and '{exp.name}' share frame '{name}' ({role}) but need values of "
                    f"different shapes: {s} in '{other}', {shape} in '{exp.name}'"
                )


def _known(experiments) -> dict[str, np.ndarray]:
    """Known frame values by name; data sets giving the same frame as known must agree."""
    known, source = {}, {}
    for exp in experiments:
        for role, name in exp.frames.items():
            key = exp.ROLES[role]
            if key not in exp.dataset.known:
                continue
            value = np.asarray(exp.dataset.known[key], dtype=float)
            if name not in known:
                known[name], source[name] = value, exp.name
                continue
            gap = float(np.max(np.abs(value - known[name])))
            if not gap <= KNOWN_ATOL:
                raise DataFormatError(
                    f"data sets '{source[name]}' and '{exp.name}' share frame '{name}' ({role}) and both give it as "
                    f"known (known['{key}']), but the values differ by up to {gap:.3g} (tolerance {KNOWN_ATOL:g}); "
                    "give it in one data set only, or name two frames"
                )
    return known
