"""``next_configurations``: the K configurations that most improve an existing calibration.

Candidates are drawn by the generator of an existing data set's kind on the (calibrated) robot, with that data
set's frames at their current values and shared with it (the same tracker, the same clamp), so the new
measurements extend the same experiment. The existing data's information is the starting point of the
selection (``kincal.analysis.design.select``, D criterion on the subspace that data and candidates together
identify): a candidate that makes an unidentifiable direction identifiable adds the most. What stays
unidentifiable even with every candidate cannot be reached by more of this experiment, and is said so.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from kincal.analysis.design import select
from kincal.data import Dataset
from kincal.errors import ModelError
from kincal.estimation import Problem, SolverOptions
from kincal.estimation.plan import identifiable_basis, plan
from kincal.experiments.sharing import frame_names
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.schema import schema_of
from kincal.simulate import GENERATORS
from kincal.simulate.noise import Noise as SimNoise

# Generator options named differently from the data set's known entry.
_OPTION = {"p_tool_marker": "markers", "T_toolA_toolB": "clamp"}


@dataclass(frozen=True, eq=False)
class Augmentation:
    """``dataset``: the chosen configurations (frames shared with ``base``); ``gained``: parameters
    unidentifiable from the existing data that the chosen ones make identifiable; ``reachable``: those the
    whole candidate pool would make identifiable; ``structural``: (parameter, why) for those no candidate of
    this experiment can make identifiable; ``rank_before`` and ``rank_after``."""

    dataset: Dataset
    base: str
    gained: tuple[str, ...]
    reachable: tuple[str, ...]
    structural: tuple[tuple[str, str], ...]
    rank_before: int
    rank_after: int


def next_configurations(robot: Robot, datasets: Sequence[Dataset], K: int, *, free="offsets",
                        noise: Noise | None = None, base: str | None = None, pool: int = 1000,
                        seed: int = 0) -> Augmentation:
    """Choose K new configurations of data set ``base`` (default: the first) for calibrating ``free`` of
    ``robot`` (the calibrated model, where the information is evaluated) together with ``datasets``."""
    datasets = list(datasets)
    ds0 = next((d for d in datasets if d.name == base), None) if base else datasets[0]
    if ds0 is None:
        raise ModelError(f"no data set named {base!r}; data sets: {', '.join(d.name for d in datasets)}")
    before = Problem.build(robot, datasets, free, noise=noise)
    p0 = plan(before, SolverOptions())
    roles = frame_names(datasets, tuple(robot.arms))[datasets.index(ds0)]
    # name ds0's frames explicitly: a second data set with the same roles would otherwise rename them
    pinned = Dataset(ds0.kind, ds0.robot, ds0.arms, ds0.q, ds0.measured, ds0.known, ds0.name, ds0.meta, roles)
    datasets[datasets.index(ds0)] = pinned
    cand = _candidates(robot, before, pinned, roles, pool, seed)
    both = Problem.build(robot, datasets + [cand], free, noise=noise)
    pb = plan(both, SolverOptions())
    V = identifiable_basis(both, pb.identifiability)
    J = pb.result.linearization.J @ V
    start, stop = _rows(both, cand.name)
    X = J[start:stop].reshape(cand.size, -1, V.shape[1])
    rest = np.concatenate([J[:start], J[stop:]])
    sel = select(X, K, "D", base=rest.T @ rest)
    chosen = cand.subset(sel.indices)
    after = plan(Problem.build(robot, datasets + [chosen], free, noise=noise), SolverOptions())
    was = _unidentifiable(p0)
    now, full = _unidentifiable(after), _unidentifiable(pb)
    structural = tuple((d.pivot, d.words) for d in pb.identifiability.directions if d.pivot in was)
    return Augmentation(chosen, ds0.name, tuple(n for n in was if n not in now), tuple(n for n in was if n not in full),
                        structural, p0.rank, after.rank)


def _unidentifiable(p) -> list[str]:
    return [e.name for e in p.estimates if not e.identifiable]


def _rows(problem: Problem, name: str) -> tuple[int, int]:
    """Rows of data set ``name`` in the stacked whitened residual."""
    start = 0
    for exp in problem.experiments:
        n = exp.size * len(exp.components())
        if exp.name == name:
            return start, start + n
        start += n
    raise ModelError(f"no data set {name!r}")


def _candidates(robot: Robot, problem: Problem, ds0: Dataset, roles, pool: int, seed: int) -> Dataset:
    """``pool`` configurations of ``ds0``'s kind on ``robot`` with ``ds0``'s frames (``roles``: role -> frame
    name) at their current values, as a data set sharing those frames (and ``ds0``'s known entries)."""
    gen = GENERATORS[ds0.kind]
    accepted = set(inspect.signature(gen).parameters)
    values = {key: problem.start.extras[roles[role]] for role, key in schema_of(ds0.kind).role_keys.items()}
    values.update(ds0.known)
    options = {_OPTION.get(k, k): v for k, v in values.items() if _OPTION.get(k, k) in accepted}
    arms = {"arms": ds0.arms} if "arms" in accepted else {"arm": ds0.arms[0]}
    ds, _, _ = gen(robot, n=pool, rng=seed, noise=SimNoise(), n_validation=2, **arms, **options)
    return Dataset(ds0.kind, ds0.robot, ds0.arms, ds.q, ds.measured, dict(ds0.known), f"{ds0.name}-candidates",
                   dict(ds0.meta), dict(roles))
