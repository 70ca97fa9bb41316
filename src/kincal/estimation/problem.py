"""The calibration problem (``Problem.build``): experiments, parameter layout, states and noise; it stacks the
experiments' residuals over the free coordinates and whitens them by each experiment's stated noise.

Whitening (per configuration, k x k): ``Sigma = diag(sigma_meas^2) + sum_arms sigma_joint^2 J_q J_q^T``, where
the data's own covariance (``Experiment.covariance``: a pose's ``pose_cov``) replaces the diagonal term,
``r_w = L^-1 r`` with ``Sigma = L L^T``. Encoder noise thus enters through the residual's Jacobian w.r.t. the
joint readings (first order). ``Sigma`` is evaluated at the linearization point of each outer iteration and
held during the inner solve. Measurement variances have a floor of (1e-9)^2 so a purely encoder-noise
closed chain stays positive definite.
"""

from __future__ import annotations

from collections import abc
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Mapping, Sequence

import numpy as np

from kincal._memo import remember
from kincal.analysis.columns import scatter_columns
from kincal.data import Dataset
from kincal.errors import ModelError
from kincal.estimation import blocks
from kincal.estimation.constraints import FrameDistance, constraint_rows
from kincal.estimation.memory import by_blocks, chunk_rows, require_memory, residual_rows
from kincal.estimation.start import starting_state
from kincal.estimation.stats import ResidualStats, residual_norms
from kincal.experiments import Experiment, build as build_experiments, checked, frame_kinds, same_bits
from kincal.kinematics import Robot
from kincal.noise import Noise, effective
from kincal.params import Layout, Prior, State, build_layout, displacement, pose_retraction_jacobians, retract
from kincal.params.layout import on_clear

VARIANCE_FLOOR = 1e-18
# The collapse test (``finalize``) reads the joint sensitivity of at most this many evenly spread configurations
# per experiment: a collapse is global.
SENSITIVITY_SAMPLES = 200
# Configurations in all up to which a problem keeps the Jacobian blocks of its linearizations at the nominal
# state and the last one for the collapse test (two copies of a Jacobian: a few MiB here).
KEPT_SAMPLES = 1000


# The whiteners' diagonals a problem keeps (``ResidualCache.made``): one per experiment and whitening of a solve.
DIAGONAL_ENTRIES = 64


class ResidualCache:
    """The last state's residuals without parameter Jacobians (with ``jq`` when encoder noise is stated):
    whitening, statistics and the scale test ask for the same state in turn (states are immutable)."""

    def __init__(self, keeps: bool = True) -> None:
        self.keeps = keeps  # False in a large problem's blocks: they would keep every block's Jacobians
        self.state: State | None = None
        self.residuals: list | None = None
        self.parts: list | None = None  # the row blocks of a large problem (``Problem.parts``)
        self.tail: tuple | None = None
        self.wants: dict[bytes, frozenset] = {}  # the blocks a set of Jacobian columns needs (``linearize``)
        # (state, experiments, their residuals with Jacobian blocks) of a small problem's linearizations at the
        # nominal state and the last one (``kept``): the collapse test reads their offset columns (``finalize``)
        self.at_nominal: tuple | None = None
        self.linearized: tuple | None = None
        self.whitening: tuple | None = None  # (residual shapes, whiteners) without encoder noise: state-free
        self.diagonals: dict[int, tuple] = {}  # id(whitener) -> (whitener, its constant diagonal or None)

    def keep(self, state: State, experiments: tuple, residuals: list, nominal: bool) -> None:
        if not self.keeps:
            return
        self.linearized = (state, experiments, residuals)
        if nominal:
            self.at_nominal = self.linearized

    def kept(self, state: State, experiments: tuple) -> list | None:
        """The residuals (with Jacobian blocks) of ``experiments`` linearized at ``state`` if kept, else None."""
        for entry in (self.linearized, self.at_nominal):
            if entry is not None and entry[0] is state and entry[1] is experiments:
                return entry[2]
        return None

    def diagonal(self, W: np.ndarray) -> np.ndarray | None:
        """``_constant_diagonal(W)``, remembered for the whiteners ``Problem._whitened_at`` made (broadcasts of a
        diagonal no one else holds: the same arrays at every evaluation of a solve)."""
        hit = self.diagonals.get(id(W))
        return hit[1] if hit is not None and hit[0] is W else _constant_diagonal(W)

    def made(self, W: np.ndarray, diagonal: np.ndarray | None = None) -> None:
        """Remember the diagonal of a whitener just made (held with it: its id is not reused meanwhile).
        ``diagonal``: the one W was made from (``np.diag`` of it, broadcast): ``_constant_diagonal(W)`` where
        finite, read without W."""
        d = _constant_diagonal(W) if diagonal is None else _finite_copy(diagonal)
        if d is not None:
            d.flags.writeable = False  # shared by every evaluation
        remember(self.diagonals, id(W), (W, d), DIAGONAL_ENTRIES)

    def get(self, state: State):
        return self.residuals if self.state is state else None

    def put(self, state: State, residuals: list) -> None:
        self.state, self.residuals = state, residuals


@dataclass(frozen=True, eq=False)
class Problem:
    """A calibration problem: what ``solve`` needs, built once by ``Problem.build``.

    ``robot``: the nominal robot (the calibrated one is this with the estimated values); ``experiments``: one
    per data set (``kincal.experiments``); ``layout``: every parameter coordinate with its name, unit, whether
    it is free and its prior; ``nominal``: the reference state (priors, reported changes,
    the gauge's "minimum change"); ``start``: where the solve starts (the nominal, or with corrected tool
    frames, ``estimation.start``); ``noise``: the stated noise per experiment; ``constraints``: known distances
    between frames; ``unknown``: the frames no data set gives (always estimated). Derived: ``free_idx`` and
    ``prior_idx`` (layout indices of the free coordinates and of those with a prior) and ``want`` (the blocks
    with a free coordinate, whose Jacobians the experiments compute).
    """

    robot: Robot
    experiments: tuple[Experiment, ...]
    layout: Layout
    nominal: State
    start: State
    noise: tuple[Noise, ...]
    constraints: tuple[FrameDistance, ...]
    unknown: tuple[str, ...]
    free_idx: np.ndarray
    prior_idx: np.ndarray
    want: frozenset[str]
    cache: ResidualCache = field(default_factory=ResidualCache, repr=False, compare=False)

    @classmethod
    def build(cls, robot: Robot, datasets: Sequence[Dataset], free: str | Sequence[str] = "offsets",
              fixed: Sequence[str] = (), priors: Mapping[str, Prior] | None = None,
              noise: Noise | Mapping[str, Noise] | None = None,
              constraints: Sequence[FrameDistance] = (), *, keep: ExitStack | None = None) -> "Problem":
        """The problem of calibrating ``robot`` from ``datasets`` (arguments as ``calibrate``'s): experiments,
        frames shared between data sets, the layout of the free and fixed parameters, stated noise per data
        set and the starting state. ``keep``: the experiments' kinematics remembered until it closes
        (``experiments.build``): a solve within it reuses the nominal ones the frames' initial guesses computed."""
        rows = residual_rows(datasets)  # counted once for both memory checks; the first before frames are guessed
        require_memory(datasets, rows=rows)  # from the data (forward kinematics of every sample)
        fixed = tuple(fixed)
        nominal_arms = State.from_robot(robot)
        exps, extras, unknown = build_experiments(datasets, nominal_arms, keep)
        arms = [a for a in robot.arms if any(a in robot.lineage(b) for e in exps for b in e.arms)]  # with ancestors
        nominal = State({a: nominal_arms.arms[a] for a in arms}, extras, frame_kinds(exps), robot.mounts)
        layout = build_layout(nominal, free, fixed=fixed, priors=priors, free_extras=unknown, arms=arms)
        # before the solve allocates anything of the data's size
        require_memory(datasets, np.count_nonzero(layout.free), rows)
        for name in unknown if len(fixed) else ():  # laid out free (``free_extras``): only ``fixed`` can hold them
            b = layout.block(name)
            if not layout.free[b.start: b.stop].all():
                raise ModelError(f"'{name}' is unknown (not given in its data set) and cannot be fixed; give its value")
        noises = _noise_per_experiment(noise, exps)
        for c in constraints:
            c.check(nominal)
        start, nominal = starting_state(nominal, exps, layout, unknown)
        return cls.assemble(robot, exps, layout, nominal, noises, start, constraints, unknown)

    @classmethod
    def assemble(cls, robot: Robot, experiments, layout: Layout, nominal: State, noise, start: State | None = None,
                 constraints=(), unknown=()) -> "Problem":
        """A problem from its parts, with the derived fields computed."""
        prior = np.isfinite(layout.prior_sigma) & layout.free
        want = frozenset(b.name for b in layout.touched(layout.free))
        return cls(robot, tuple(experiments), layout, nominal, nominal if start is None else start, tuple(noise),
                   tuple(constraints), tuple(unknown), layout.free.nonzero()[0], prior.nonzero()[0], want)

    def with_measurements(self, datasets: Sequence[Dataset]) -> "Problem | None":
        """This problem with ``datasets`` in place of its data sets when they differ from them in measured values only
        (``same_structure``: kinds, names, arms, frames, joint readings, known values, stated noise), no frame is
        unknown and the start was not corrected: the layout, nominal, start and noise are reused, and what
        ``build`` checks of measured values is checked again (finite, the kind's ``check``, the memory, the
        start). None where that does not hold: ``build`` the problem then. A Monte Carlo study's repeats differ so."""
        if self.unknown or self.start is not self.nominal or len(datasets) != len(self.experiments) or not all(
                same_structure(e.dataset, d) for e, d in zip(self.experiments, datasets)):
            return None
        require_memory(datasets, len(self.free_idx))
        exps = [checked(ds, e.frames) for e, ds in zip(self.experiments, datasets)]
        start, nominal = starting_state(self.nominal, exps, self.layout, self.unknown)
        if start is not self.nominal or nominal is not self.nominal:
            return None
        return replace(self, experiments=tuple(exps), cache=ResidualCache())

    @cached_property
    def joint_noise(self) -> bool:
        """Whether any experiment states encoder noise (whitening then depends on the state through J_q)."""
        return any(nz.joint_sigma() > 0 for nz in self.noise)

    def residuals(self, state: State) -> list:
        """Residuals at ``state`` without parameter Jacobians (with ``jq`` when encoder noise is stated)."""
        res = self.cache.get(state)
        if res is None:
            res = self._residuals(state, self.joint_noise)
            self.cache.put(state, res)
        return res

    def _residuals(self, state: State, jq: bool) -> list:
        """The experiments' residuals at ``state`` (block by block when ``blocked``), no parameter Jacobians."""
        if not self.blocked:
            return [exp.residual(state, want=set(), jq=jq) for exp in self.experiments]
        return blocks.gather(self.parts(), len(self.experiments),
                             lambda part: part.experiments[0].residual(state, want=set(), jq=jq))

    def parts(self) -> list:
        """(experiment index, row range, sub-problem) of every block of configurations (``estimation.blocks``);
        the sub-problems hold no prior or constraint rows (``tail``)."""
        if self.cache.parts is None:
            per = chunk_rows(len(self.free_idx)) if self._by_blocks else self._rows
            self.cache.parts = [(i, rows, blocks.part_problem(self, i, rows, ResidualCache(keeps=False)))
                                for i, rows in blocks.split(self.experiments, lambda e: max(per // len(e.components()), 1))]
        return self.cache.parts

    def tail(self) -> "Problem | None":
        """The prior and constraint rows as a problem without experiments (None without any)."""
        if self.cache.tail is None:
            self.cache.tail = (blocks.tail_problem(self, ResidualCache(keeps=False)),)
        return self.cache.tail[0]

    @cached_property
    def blocked(self) -> bool:
        """Whether the problem is evaluated by blocks (``memory.by_blocks``; decided once, with ``parts``). Not
        by blocks, ``parts`` are the experiments whole: no need to make them to know."""
        return self._by_blocks and len(self.parts()) > len(self.experiments)

    @cached_property
    def _rows(self) -> int:
        """The experiments' residual rows."""
        return sum(e.size * len(e.components()) for e in self.experiments)

    @cached_property
    def _by_blocks(self) -> bool:
        """Whether the experiments' rows call for blocks (``memory.by_blocks``)."""
        return by_blocks(self._rows, len(self.free_idx))

    @cached_property
    def _small(self) -> bool:
        """Small enough to keep a linearization's Jacobian blocks for the report (``ResidualCache.keep``)."""
        sizes = [e.size for e in self.experiments]
        return max(sizes, default=0) <= SENSITIVITY_SAMPLES and sum(sizes) <= KEPT_SAMPLES

    @property
    def free_names(self) -> list[str]:
        return [self.layout.names[i] for i in self.free_idx]

    def full_delta(self, delta_free: np.ndarray) -> np.ndarray:
        d = np.zeros(self.layout.size)
        d[self.free_idx] = delta_free
        return d

    def whiteners(self, state: State) -> list[np.ndarray]:
        """Per experiment (N, k, k) inverse Cholesky factors of the residual covariance at ``state``."""
        return self._whiteners_of(self.residuals(state))

    def _whiteners_of(self, residuals) -> list[np.ndarray]:
        shapes = tuple(res.r.shape for res in residuals)
        kept = self.cache.whitening
        if kept is not None and kept[0] == shapes and not self.joint_noise:  # not J_q: the state's own ones
            return list(kept[1])
        out = self._whitened_at(residuals)
        if not self.joint_noise:  # from the experiments' noise and the residuals' shapes alone
            self.cache.whitening = (shapes, tuple(out))
        return out

    def _whitened_at(self, residuals) -> list[np.ndarray]:
        out = []
        for exp, nz, res in zip(self.experiments, self.noise, residuals):
            own, sj = exp.covariance(), nz.joint_sigma()
            if own is None:
                var = np.maximum(stated_sigmas(exp, nz) ** 2, VARIANCE_FLOOR)
                if sj == 0:  # constant: a diagonal, broadcast over samples
                    d = 1.0 / np.sqrt(var)
                    out.append(np.broadcast_to(np.diag(d), res.r.shape + (res.r.shape[1],)))
                    self.cache.made(out[-1], d)
                    continue
                own = np.diag(var)
            cov = np.broadcast_to(own, res.r.shape + (res.r.shape[1],)).copy()
            for jq in res.jq.values() if sj > 0 else ():
                cov += sj**2 * (jq @ np.swapaxes(jq, -1, -2))
            out.append(np.linalg.inv(np.linalg.cholesky(cov)))
        return out

    def linearize(self, state: State, whiteners=None, cols=None):
        """Whitened residual (m,) and Jacobian at ``state`` in one evaluation of the experiments.

        ``cols``: layout indices of the Jacobian's columns (default: the free coordinates; the scale test adds
        fixed ones). ``whiteners=None``: whiten at ``state`` from the same evaluation's ``J_q``.
        Returns ``(r, J, whiteners, residuals)``, the last the experiments' residuals before whitening.
        """
        cols = self.free_idx if cols is None else np.asarray(cols)
        want = self.want if cols is self.free_idx else self.cache.wants.get(cols.tobytes())  # ``assemble``'s
        if want is None:
            want = self.cache.wants[cols.tobytes()] = _blocks_of(self.layout, cols)
        fresh = whiteners is None
        res = [exp.residual(state, want=want, jq=fresh and self.joint_noise) for exp in self.experiments]
        W = self._whiteners_of(res) if fresh else whiteners
        if fresh or not self.joint_noise:  # statistics at this state need no second evaluation
            self.cache.put(state, res)
        if self._small:  # keeping them costs little
            self.cache.keep(state, self.experiments, res, state is self.nominal)
        r, J = self._stack(state, res, W, cols, {})
        return r, J, W, [x.r for x in res]

    def length_part(self, residuals, whiteners) -> np.ndarray:
        """The whitened stacked residual (from the experiments' ``residuals`` before whitening) with only its
        length components kept (prior and constraint rows zero).

        Where no measured length enters a loop (clamp, dual, socket, plane, distance with lengths all free),
        scaling every length by ``1 + e`` changes the residual by exactly ``e`` times this, to first order:
        the scale test compares it with the Jacobian's scale column."""
        out = []
        for exp, W, r in zip(self.experiments, whiteners, residuals):
            keep = np.array([c.length for c in exp.components()], float)
            out.append((W @ (r * keep)[:, :, None]).ravel())
        if len(self.prior_idx):
            out.append(np.zeros(len(self.prior_idx)))
        out.append(np.zeros(len(self.constraints)))  # a known distance does not scale with the robot
        return np.concatenate(out)

    def evaluate(self, state0: State, delta_free: np.ndarray, whiteners, jac: bool = True):
        """Whitened stacked residual (m,) at ``retract(state0, delta)`` and, if asked, its Jacobian (m, p_free)."""
        # no step (a trial point retracted already): the same values as retracting by zero
        moves = delta_free.any()
        delta = self.full_delta(delta_free) if moves or jac else None
        state = retract(state0, self.layout, delta, tangents=jac) if moves else state0
        if not jac:
            return self._stack(state, self._residuals(state, False), whiteners, None, {})[0], None
        Rl = {k: v for k, v in pose_retraction_jacobians(self.layout, delta).items() if k in self.want}
        res = [exp.residual(state, want=self.want, jq=False) for exp in self.experiments]
        return self._stack(state, res, whiteners, self.free_idx, Rl)

    def _stack(self, state, residuals, whiteners, cols, Rl):
        """Whiten and stack residuals and (``cols`` not None) the Jacobian columns ``cols`` of the layout;
        ``Rl``: retraction Jacobians of pose blocks stepped away from their linearization point."""
        rs, Js = [], []
        for res, W in zip(residuals, whiteners):
            d = self.cache.diagonal(W)
            rs.append((res.r * d).ravel() if d is not None else (W @ res.r[:, :, None]).ravel())
            if cols is None:
                continue
            N, k = res.r.shape
            J = scatter_columns(res.jac, self.layout, cols, (N, k), Rl)  # a new array: whitened in place
            Js.append((np.multiply(J, d[:, None], out=J) if d is not None else W @ J).reshape(N * k, -1))
        if len(self.prior_idx):
            disp, D = displacement(state, self.nominal, self.layout, jacobian=cols is not None)
            sig = self.layout.prior_sigma[self.prior_idx]
            rs.append((disp[self.prior_idx] - self.layout.prior_mean[self.prior_idx]) / sig)
            if cols is not None:
                Dfull = D[self.prior_idx]
                for name, Jl in Rl.items():
                    b = self.layout.block(name)
                    Dfull[:, b.start: b.stop] = Dfull[:, b.start: b.stop] @ Jl
                Js.append(Dfull[:, cols] / sig[:, None])
        if len(self.constraints):
            rc, Jc = constraint_rows(self.constraints, state, self.layout, Rl, cols)
            rs.append(rc)
            if cols is not None:
                Js.append(Jc)
        r = _joined(rs)
        return (r, _joined(Js)) if cols is not None else (r, None)

    def statistics(self, state: State, whiteners=None) -> list[ResidualStats]:
        """Per experiment: samples, position / orientation RMS and max (norm per sample), whitened chi^2."""
        W = self.whiteners(state) if whiteners is None else whiteners
        out = []
        for exp, Wi, res in zip(self.experiments, W, self.residuals(state)):
            r = res.r
            out.append(ResidualStats(experiment=exp.name, kind=exp.kind, samples=exp.size,
                                     **residual_norms(r, exp.components()),
                                     chi2=float(np.sum(np.einsum("nij,nj->ni", Wi, r) ** 2)), dof=int(r.size)))
        return out


def same_structure(a: Dataset, b: Dataset) -> bool:
    """Whether data sets ``a`` and ``b`` differ in their measured values only: the same kind, robot, name, arms,
    frames and stated noise, the same measured entries with their shapes, and joint readings and known values
    equal bit for bit (what a problem's experiments, frames, layout and noise are made of)."""
    if (a.kind, a.robot, a.name, a.arms, dict(a.frames), a.meta.get("noise")) != \
            (b.kind, b.robot, b.name, b.arms, dict(b.frames), b.meta.get("noise")):
        return False
    if {k: np.shape(v) for k, v in a.measured.items()} != {k: np.shape(v) for k, v in b.measured.items()}:
        return False
    return all(_same_arrays(x, y) for x, y in ((a.q, b.q), (a.known, b.known)))


def _same_arrays(x: Mapping, y: Mapping) -> bool:
    """The same keys, in the same order, each with arrays equal bit for bit (``same_bits``: dtype, shape and bytes,
    so a -0.0 is not a 0.0 here)."""
    return list(x) == list(y) and all(same_bits(np.asarray(x[k]), np.asarray(y[k])) for k in x)


def triangular_factor(columns: Sequence[np.ndarray], panels: bool = False) -> np.ndarray:
    """``numpy.linalg.qr(np.column_stack(columns), mode="r")``, the same numbers without its two copies of the
    tall matrix: the columns are written once into a Fortran-ordered array that LAPACK's ``geqrf`` factorizes in
    place (numpy's ``qr`` copies its argument, then copies it again into Fortran order). C-ordered, as numpy's.
    ``panels``: LAPACK's ``geqrt`` on panels of ``QR_PANEL`` columns instead when the matrix has ``QR_TALL`` rows
    or more (``geqrf`` is unblocked below 128 columns): the same R to round-off, a third faster at 600 x 46."""
    from scipy.linalg.lapack import dgeqrf, dgeqrt  # here: importing scipy.linalg costs more than importing kincal

    cols = [c.reshape(len(c), -1) for c in columns]
    m, n = len(cols[0]), sum(c.shape[1] for c in cols)
    A = np.empty((m, n), order="F")
    at = 0
    for c in cols:
        A[:, at: at + c.shape[1]] = c
        at += c.shape[1]
    k = min(m, n)
    if panels and m >= QR_TALL and n >= QR_PANEL:
        qr, _, info = dgeqrt(QR_PANEL, A, overwrite_a=1)
    else:
        qr, _, _, info = dgeqrf(A, lwork=max(1, 64 * n), overwrite_a=1)
    if info != 0:  # an argument LAPACK rejects: numpy's error
        return np.linalg.qr(np.column_stack(columns), mode="r")
    R = np.zeros((k, n))  # C-ordered; the upper triangle copied in, the zeros below as ``np.triu``'s
    np.copyto(R, qr[:k], where=_UPPER[:k, :n] if n <= len(_UPPER) else ~np.tri(k, n, -1, dtype=bool))
    return R


# The blocked QR's panel width (fastest of 2..16 at 150-3000 rows, 31-46 columns; OpenBLAS, one thread) and the
# rows from which it pays (at 100 rows it is slower than ``geqrf``, from ~200 faster: 600 x 46 in 130 us, not 187)
QR_PANEL, QR_TALL = 8, 256


# ``~np.tri(k, n, -1, dtype=bool)`` of every k <= n up to its size is its leading block: one constant table
_UPPER = ~np.tri(128, 128, -1, dtype=bool)
_UPPER.flags.writeable = False


def _blocks_of(layout, cols: np.ndarray) -> frozenset:
    """The names of the blocks holding a column of ``cols`` (``Layout.holding``: an empty block is never found)."""
    return frozenset(b.name for b in layout.holding(cols))


def _joined(parts: list) -> np.ndarray:
    """``np.concatenate(parts)`` (rows); a single part as it is (each part here is a new array of its own)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _constant_diagonal(W: np.ndarray) -> np.ndarray | None:
    """The diagonal (k,) of whiteners (N, k, k) that are one diagonal matrix for every sample (stated noise, no
    encoder noise: ``_whiteners_of``), else None. Whitening by it scales rows: the same numbers as the product
    (whose other terms are exact zeros)."""
    if W.ndim != 3 or W.strides[0] != 0:
        return None
    D = W[0]
    d = np.diagonal(D)  # ``D - diag(d)`` all zeros: no nonzero (nor NaN) entry off the diagonal, d finite
    return _finite_copy(d) if np.count_nonzero(D) == np.count_nonzero(d) else None


def _finite_copy(d: np.ndarray) -> np.ndarray | None:
    """A copy of the diagonal ``d`` where every entry is finite, else None (``_constant_diagonal``'s test)."""
    return d.copy() if np.isfinite(d).all() else None


def _noise_per_experiment(noise, exps) -> list[Noise]:
    """The noise of every experiment by the one rule (``kincal.noise.effective``): ``noise`` (one ``Noise`` for
    all, or a mapping data set name -> Noise) where it states a quantity, else the data set's stated noise
    (``Dataset.meta["noise"]``), else ``kincal.noise.DEFAULT``."""
    by_set = isinstance(noise, abc.Mapping)  # ``typing.Mapping``'s check, without its wrapper
    if by_set:
        bad = set(noise) - {e.name for e in exps}
        if bad:
            raise ModelError(f"noise given for unknown data set(s) {sorted(bad)}; data sets: {[e.name for e in exps]}")
    return [_effective(noise.get(e.name) if by_set else noise, e.dataset.meta.get("noise")) for e in exps]


def _effective(explicit: Noise | None, stated: Mapping | None) -> Noise:
    """``effective(explicit, stated)``, remembered by their values (a batch or a Monte Carlo study states the same
    noise at every call, in a new ``Noise`` each time); the answer is shared, a ``Noise`` being immutable."""
    key = _noise_key(explicit, stated)
    hit = _NOISES.get(key) if key is not None else None
    if hit is None:
        hit = effective(explicit, stated)
        if key is not None:
            remember(_NOISES, key, hit, NOISE_ENTRIES)
    return hit


def _noise_key(explicit: Noise | None, stated: Mapping | None) -> str | None:
    """The values ``effective`` reads, as their repr (exact for these types: it tells -0.0 from 0.0 and 1 from
    1.0); None when one is of another type (nothing remembered then)."""
    if explicit is not None and type(explicit) is not Noise:
        return None
    named = () if explicit is None else (explicit.position, explicit.orientation, explicit.joint, explicit.backlash)
    other, given = ({} if explicit is None else explicit.other), (stated or {})
    if not (_VALUE_TYPES.issuperset(map(type, named)) and _VALUE_TYPES.issuperset(map(type, other.values()))
            and _VALUE_TYPES.issuperset(map(type, given.values())) and _NAME_TYPES.issuperset(map(type, other))
            and _NAME_TYPES.issuperset(map(type, given))):
        return None
    return repr((explicit is None, named, tuple(other.items()), tuple(given.items())))


# _effective's memory: the stated noises' values -> the noise in effect, oldest first
_NOISES: dict[str, Noise] = {}
NOISE_ENTRIES = 64
_VALUE_TYPES, _NAME_TYPES = frozenset((float, int, type(None))), frozenset((str,))


@on_clear
def clear_noise_cache() -> None:
    """Forget what ``_effective`` remembered (``kincal.params.clear_caches`` runs this)."""
    _NOISES.clear()


def stated_sigmas(exp: Experiment, noise: Noise) -> np.ndarray:
    """Per residual component of ``exp``, the standard deviation ``noise`` states for its quantity."""
    out = []
    for q in exp.components():
        sigma = noise.sigma(q)
        if sigma is None:
            raise ModelError(
                f"data set '{exp.name}' ({exp.kind}) has {q.name} residuals ({q.unit}) but the stated noise gives no "
                f"{q.name} standard deviation; state it (Noise({q.name}=...) or noise: {{{q.name}_<unit>: ...}})")
        out.append(sigma)
    return np.array(out, dtype=float)
