"""Identifiability in one place: rank and null space of a whitened identification Jacobian, the exact
symmetries held (``symmetries``), each null direction named (``naming``). ``identify`` is the entry point for
one linearization of a calibration problem (``linearization.Linearization``); ``analyse`` the matrix-level core.

Rank: singular values of the whitened Jacobian after scaling every column to unit norm (so units and
the size of a parameter's effect do not matter). A direction is unidentifiable when its singular value is
below ``rtol * sigma_max`` (default ``rtol = 1e-9``: exact symmetries of noise-free data sit at ~1e-15,
badly excited but identifiable directions well above). Directions below ``weak_rtol`` (1e-5) but above
``rtol`` are reported as weakly identifiable, and so are the directions below a gap of more than
``WEAK_GAP`` (100x) between consecutive singular values when they lie below 1e-3 of the largest: such a
cluster is determined by little more than the noise even if no fixed threshold catches it.

Null directions are presented in reduced row-echelon form over the parameters in priority order
(arm offsets, twists, home, base, tool, then experiment frames): each has one *pivot* parameter with
coefficient 1 and the parameters it trades off against. The scale direction (all lengths scaled
together, thesis Sec. 2.11) is tested explicitly and reported as scale.

The words print only what the null space determines. The echelon form of a subspace is a function of the
subspace and the order alone (units do not matter), and each coefficient's uncertainty follows from the form
itself: row i, column j moves by at most ``a |R_i| sqrt(1 + |R[:, j]|^2)`` when the basis turns by the angle
``a`` (``NAMING_ACCURACY``, 1e-10). A coefficient is printed to the digits that leaves (three at most), and a
parameter is named as a partner where its coefficient is at least 1e-3 of its row's largest and ten times its
uncertainty. With scale unidentifiable, the named directions are those orthogonal to the scale direction
``s + u`` (``symmetries.scale_null``: ``Rf u = b``, free parameters standing in for the fixed lengths), so u must
be the data's: ``analyse`` solves for it with its own spectrum of ``Rf``, cut at the rank (``_scale_at_rank``),
and takes the minimum-norm solution in natural units (``_minimum_norm``, against the null basis it builds anyway).
numpy's ``lstsq`` cut at eps, which keeps null singular values near 1e-13 in a dual arm: round-off added other
null directions to u (3e-4 under one-ulp changes of the joint readings), and the echelon form of the directions
orthogonal to it (a pivot block of condition 3.5e4) moved printed coefficients by up to 28 %. Where numpy's cut
cuts every null singular value (a well-determined single arm), the two are the same to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from typing import Callable, Sequence

import numpy as np

from kincal.analysis.covariance import right_svd
from kincal.analysis.factor import Factor
from kincal.analysis.linalg import complete_q, lstsq, norm, norms, svd, thin_svd
from kincal.analysis.linalg import null_and_range as _null_and_range
from kincal.analysis.linearization import Linearization, unit_columns
from kincal.analysis.naming import context, degenerate, describer
from kincal.analysis.symmetries import Structure, consistent_nulls, rotation_nulls, scale_null
from kincal.params import Layout

# No identifiable direction whose relative singular value is at least this is weak (with ``weak_rtol`` below it).
WEAK_CEILING = 1e-3
IDENTIFIABLE_TOL = 1e-6  # a parameter is identifiable when its row of the (scaled) null basis is below this


@dataclass(frozen=True)
class Direction:
    """One unidentifiable direction: ``pivot`` moves by 1, ``partners`` by their coefficients (natural units)."""

    pivot: str
    partners: tuple[tuple[str, float], ...]
    vector: np.ndarray  # (p,) over the analysed parameters, natural units
    words: str


@dataclass(frozen=True)
class Identifiability:
    names: tuple[str, ...]
    rank: int
    singular_values: np.ndarray  # of the column-scaled whitened Jacobian, descending
    rtol: float
    null_space: np.ndarray  # (p, k) orthonormal basis in natural units
    range_space: np.ndarray  # (p, p - k) orthonormal complement in natural units
    identifiable: np.ndarray  # (p,) bool
    scale_unidentifiable: bool
    directions: tuple[Direction, ...]
    weak: tuple[str, ...] = ()
    messages: tuple[str, ...] = field(default=())
    weak_vectors: np.ndarray | None = None  # (p, w) the directions of ``weak`` in natural units, unit norm
    degenerate: bool | None = None  # no arm parameter identifiable, only frames (judged by ``identify`` reports)
    naming_basis: np.ndarray | None = field(default=None, repr=False)  # the null basis ``directions`` name
    # the analysed Jacobian's own SVD where ``null_space`` is exactly its trailing directions (``analysis.factor``:
    # the Gauss-Newton step and the covariance without another decomposition), else None
    factor: Factor | None = field(default=None, repr=False, compare=False)

    @property
    def deficiency(self) -> int:
        return len(self.names) - self.rank

    @property
    def condition(self) -> float:
        s = self.singular_values[: self.rank]
        return float(s[0] / s[-1]) if self.rank else np.inf

    def unidentifiable_names(self) -> list[str]:
        return [n for n, ok in zip(self.names, self.identifiable) if not ok]


def identify(lin: Linearization, layout: Layout, experiments: Sequence, *, rtol: float = 1e-9,
             priority: Sequence[int] | None = None, report: bool = True,
             structural: np.ndarray | None = None, hold: np.ndarray | None = None,
             structure: Structure | None = None) -> Identifiability:
    """The identifiability of the free coordinates at one linearization: the one entry point of the solver.

    Rank and null space of ``lin``'s whitened Jacobian with the exact symmetries held (the scale without a
    measured length, ``symmetries.scale_null``, when ``lin`` has the scale test's columns; the rotations about
    a first joint axis, ``symmetries.rotation_nulls``). ``report``: also name the null directions in words
    (``naming``) and judge whether the data are degenerate; the solver's intermediate iterations need only the
    rank, the null space and the weak directions (``directions`` is then empty). ``priority``: free-coordinate
    order for the pivots of the named directions. ``structural`` (p, k): exact gauges of the start (natural
    units); those the estimate lifts only slightly are reported as weakly identifiable with their names
    (``near_gauges``: a coupling of parallel axes, whose exact gauge at the nominal model the estimated tilts
    of the axes lift a little). ``hold`` (p, k): the exact gauges of the rigid model, which only the weight
    lifts (natural units, ``estimation.gauge.rigid_gauges``): held by pinning one coordinate per direction
    (``pivot_rows`` in ``priority``), named, with a message saying why. ``structure``: the solve's
    (``symmetries.Structure``, what the symmetry tests read of the problem's structure alone), used where it
    ``fits`` ``lin``.
    """
    if structure is not None and not structure.fits(lin, layout, experiments, rtol):
        structure = None
    names = structure.names if structure is not None else [layout.names[i] for i in lin.free]
    # evaluated by ``analyse`` after its spectrum of lin.Rf, which cuts the scale's solve at the rank
    scale = partial(scale_null, lin, layout, structure) if lin.every else None
    held = rotation_nulls(lin, layout, experiments, structure)
    gauges = partial(consistent_nulls, lin, layout, experiments, rtol, structure=structure)
    J, pins, colnorm = lin.Rf, [], lin.colnorm
    if hold is not None:
        hold, pins = _held(hold, priority, len(names), structure)
        J = lin.Rf.copy()
        J[:, pins] = 0.0  # the pinned coordinates do not move: exact nulls, the rest analysed without them
        colnorm = None
        scale = scale() if scale is not None else None  # numpy's solve: the spectrum is not Rf's own
        scale, held, gauges = _unpinned(hold, pins, scale, held, gauges)
    ana = analyse(J, names, rtol=rtol, priority=priority, scale=scale, held=held, gauges=gauges, name=False,
                  colnorm=colnorm)
    if pins:
        ana = _pinned(ana, hold, pins)
    return named(ana, lin, layout, experiments, priority, structural) if report else ana


def _held(hold: np.ndarray, priority, p: int, structure: Structure | None) -> tuple[np.ndarray, list[int]]:
    """The orthonormal basis of ``hold`` and its pinned rows (``pivot_rows`` in ``priority``). Remembered on the
    solve's ``structure`` by the values of ``hold`` and ``priority``, all they depend on: the solve holds the
    same gauges at every linearization (``iterate`` takes them once, at the start)."""
    order = range(p) if priority is None else priority
    if structure is None:
        H = _orth(hold)
        return H, pivot_rows(H, order)
    key = ("held", hold.dtype.str, hold.shape, hold.tobytes(), None if priority is None else tuple(priority))
    hit = structure.derived.get(key)
    if hit is None:
        H = _orth(hold)
        H.flags.writeable = False  # shared by the solve's linearizations
        hit = structure.derived[key] = (H, pivot_rows(H, order))
    return hit


def pivot_rows(L: np.ndarray, order) -> list[int]:
    """Rows of the orthonormal basis L (p, k), first in ``order``, that together span its k directions: holding
    those coordinates removes them. A row counts when what it adds is not small against a unit row."""
    Q, chosen = np.zeros((L.shape[1], 0)), []
    for j in order:
        if len(chosen) == L.shape[1]:
            break
        r = L[j] - Q @ (Q.T @ L[j])
        if np.linalg.norm(r) > 0.1:
            Q = np.column_stack([Q, r / np.linalg.norm(r)])
            chosen.append(int(j))
    return sorted(chosen)


def _unpinned(hold: np.ndarray, pins: list[int], scale, held, gauges):
    """The exact symmetries of the cost moved off the pinned coordinates along the held directions: what they
    are among the coordinates that still move. One within the held directions (to well within their turn since
    the start, where ``hold`` was taken) is held with them already: dropped."""
    def move(v):
        if v is None:
            return None
        u = v / np.linalg.norm(v)
        if np.linalg.norm(u - hold @ (hold.T @ u)) < 0.5:
            return None
        return v - hold @ lstsq(hold[pins], v[pins])

    def moved_gauges(plain: int):
        G = gauges(plain - len(pins))
        if G is None or not G.shape[1]:
            return G
        kept = [w for w in (move(g) for g in G.T) if w is not None]
        return np.column_stack(kept) if kept else np.zeros((len(G), 0))

    return move(scale), [w for w in (move(h) for h in held) if w is not None], moved_gauges


def _pinned(ana: Identifiability, hold: np.ndarray, pins: list[int]) -> Identifiability:
    """``ana`` of the Jacobian without the pinned columns, its null space the held directions (the rigid
    model's gauges, named with the coordinates they trade off against) and the rest of its own; the solver
    still moves the coordinates of ``range_space`` only, the pinned ones never."""
    N = ana.null_space.copy()
    N[pins] = 0.0
    U, S, _ = svd(N, full_matrices=False)
    null = _orth(np.column_stack([hold, U[:, S > 0.5]]))
    names = _list([ana.names[i] for i in pins], 8)
    return replace(ana, null_space=null, naming_basis=null, identifiable=np.linalg.norm(null, axis=1) < 1e-6,
                   factor=None,
                   messages=ana.messages + (RIGID_HELD.format(len(pins), names),))


RIGID_HELD = ("{} direction(s) that the rigid model cannot identify (named above) would be lifted only by the weight: "
              "held, {} keeping their starting values. The weight sees them through the centres of mass, given in "
              "the nominal frames that these directions carry along (a convention), or through a tilt relative to "
              "gravity, bilinearly in the compliances: too weakly to estimate them (docs/calibration.md)")


def named(ana: Identifiability, lin: Linearization, layout: Layout, experiments: Sequence,
          priority: Sequence[int] | None = None, structural: np.ndarray | None = None) -> Identifiability:
    """``identify(lin, ..., report=True)`` from its ``report=False`` analysis ``ana`` of the same linearization
    (the solver's last one, say) without analysing again: the null directions named in words (after the scale
    message, before the weak ones) and the degenerate judgement; ``structural`` as in ``identify``. ``ana`` itself when it is named already."""
    if ana.degenerate is not None:
        return ana
    ana = _named(replace(ana, degenerate=judge(ana, lin, layout)), lin.state, lin.free, layout, experiments, priority)
    if structural is not None and structural.shape[1]:
        ana = _with_lifted_gauges(ana, near_gauges(lin.Rf, structural))
    return ana


def judge(ana: Identifiability, lin: Linearization, layout: Layout) -> bool:
    """Whether the data of ``lin`` are degenerate (``naming.degenerate``), from ``ana``'s spectrum."""
    return degenerate(lin.Rf, ana.rank, ana.rtol, layout, lin.free, ana.singular_values)


def _named(ana: Identifiability, state, free: np.ndarray, layout: Layout, experiments: Sequence,
           priority: Sequence[int] | None) -> Identifiability:
    """``ana`` with its null directions named in words at ``state`` (``free``: layout indices of its columns)."""
    order = list(range(len(ana.names))) if priority is None else list(priority)
    basis = ana.naming_basis
    describe = describer(state, free, layout, experiments) if basis.shape[1] else None  # FK: only if needed
    directions = tuple(_directions(basis, order, ana.names, describe, context(layout, experiments)))
    k = int(ana.scale_unidentifiable)  # the scale message comes first
    messages = ana.messages[:k] + tuple(d.words for d in directions) + ana.messages[k:]
    return replace(ana, directions=directions, messages=messages)


@dataclass(frozen=True, eq=False)
class DeferredReport:
    """The report ``identify(lin, ..., report=True)`` gives, named only when first asked for (``report``):
    the solver's report at the start, which no step of the solve reads in words. ``analysis``: the
    ``report=False`` analysis of the linearization; ``degenerate``: judged at once (the solver stops on it).
    It keeps the linearization's state and free columns, not its Jacobian."""

    analysis: Identifiability
    degenerate: bool
    state: object
    free: np.ndarray
    layout: Layout
    experiments: tuple
    priority: tuple[int, ...] | None

    @classmethod
    def of(cls, ana: Identifiability, lin: Linearization, layout: Layout, experiments: Sequence,
           priority: Sequence[int] | None = None) -> "DeferredReport":
        return cls(ana, judge(ana, lin, layout), lin.state, lin.free, layout, tuple(experiments),
                   None if priority is None else tuple(priority))

    @cached_property
    def report(self) -> Identifiability:
        """``named``'s report (without ``structural``), computed once."""
        return _named(replace(self.analysis, degenerate=self.degenerate), self.state, self.free, self.layout,
                      self.experiments, self.priority)


def coupling_gauges(state, first: "DeferredReport | None") -> np.ndarray | None:
    """The start's null basis when an arm has joint couplings (the ``structural`` of ``identify``), else None."""
    coupled = any(getattr(a, "coupling", None) is not None for a in state.arms.values())
    return first.analysis.null_space if coupled and first is not None else None


NEAR_GAUGE_RTOL = 1e-2  # a start's exact gauge lifted to below this (relative singular value) is reported weak


def near_gauges(J: np.ndarray, structural: np.ndarray, rtol: float = NEAR_GAUGE_RTOL,
                floor: float = 0.0) -> np.ndarray:
    """The directions within span(``structural``) (p, k, natural units) whose relative singular value in the
    column-scaled ``J`` is below ``rtol`` (and not below ``floor``): (p, j) natural units. Exact gauges of the nominal model that the
    estimate lifts only by its own small deviations (three parallel axes coupled to sum to zero turn slightly
    apart) rest on those deviations alone: little more than the noise determines them."""
    Js, c = unit_columns(J)
    G = _orth(c[:, None] * structural)
    smax = np.linalg.norm(Js, 2) if Js.size else 0.0
    if G.shape[1] == 0 or smax == 0:
        return np.zeros((len(c), 0))
    _, S, Vt = svd(Js @ G, full_matrices=False)
    small = Vt[(S < rtol * smax) & (S >= floor * smax)]
    return (G @ small.T) / c[:, None]


def _with_lifted_gauges(ana: Identifiability, near: np.ndarray) -> Identifiability:
    """``ana`` with the directions of ``near`` (natural units) that are neither unidentifiable nor weak there
    added to its weakly identifiable directions, named."""
    known = np.column_stack([ana.null_space] + ([ana.weak_vectors] if ana.weak_vectors is not None else []))
    Q = _orth(known) if known.shape[1] else known
    new = []
    for x in near.T:
        x = x / np.linalg.norm(x)
        if np.linalg.norm(x - Q @ (Q.T @ x)) > 0.5:  # a new dimension, not one already reported
            new.append(x)
            Q = _orth(np.column_stack([Q, x]))
    if not new:
        return ana
    weak = tuple(_top_names(x, ana.names) for x in new)
    words = [f"weakly identifiable direction (an exact gauge of the nominal model, e.g. of coupled parallel axes, "
             f"that the estimate lifts only slightly; its estimate rests on little more than the noise): {w}"
             for w in weak]
    vectors = np.column_stack(([ana.weak_vectors] if ana.weak_vectors is not None else []) + new)
    return replace(ana, weak=ana.weak + weak, weak_vectors=vectors, messages=ana.messages + tuple(words))


def analyse(
    J: np.ndarray,
    names: Sequence[str],
    *,
    rtol: float = 1e-9,
    weak_rtol: float = 1e-5,
    # the scale direction (p,) when no measured length enters, always held; or a function of a solver of
    # ``J u = b`` giving it (``symmetries.scale_null``: the solve is then cut at the spectrum's rank)
    scale: np.ndarray | Callable | None = None,
    held: Sequence[np.ndarray] = (),  # other exact symmetries of the cost (p,), held even where residuals lift them
    # (p, k) basis of the noise-free problem's exact null space, held likewise; or a function of the plain null
    # space's dimension giving it (``symmetries.consistent_nulls``: a known structure skips the work)
    gauges: np.ndarray | Callable[[int], np.ndarray | None] | None = None,
    priority: Sequence[int] | None = None,
    describe: Callable[[np.ndarray], str] | None = None,
    context: str = "",
    name: bool = True,
    colnorm: np.ndarray | None = None,
) -> Identifiability:
    """Analyse the whitened Jacobian J (m, p) whose columns are the parameters ``names``; ``name``: also the null
    directions in reduced row-echelon form (``directions`` and their messages); ``colnorm``: J's column norms,
    when known (``Linearization.colnorm``)."""
    names = tuple(names)
    p = J.shape[1]
    sv = _spectrum(J, rtol, colnorm)
    if callable(gauges):
        gauges = gauges(p - sv.rank)
    u = None
    if callable(scale):
        scale, u = _scale_at_rank(scale, J, sv)
    has_scale = scale is not None and norm(scale) > 0
    Ns, rank, lifted, held_scale, spectral = hold_exact(sv.Vt[sv.rank:].T, sv.c, ([scale] if has_scale else [])
                                                        + list(held), has_scale, gauges)
    identifiable = norms(Ns, 1) < IDENTIFIABLE_TOL
    N, R = _null_and_range(Ns / sv.c[:, None], scratch=True)
    if has_scale and u is not None and sv.rank < p:
        # N's first columns span Ns's first (the spectrum's null space, where the gauges did not replace it)
        N0 = N[:, :p - sv.rank] if spectral else complete_q(sv.Vt[sv.rank:].T / sv.c[:, None])[:, :p - sv.rank]
        scale = _minimum_norm(scale, u, N0)
    weak_idx = _weak_indices(sv, rank, rtol, weak_rtol, lifted)
    weak = tuple(_top_names(sv.Vt[i], names) for i in weak_idx)
    weak_vectors = _weak_vectors(sv, weak_idx)
    messages: list[str] = []
    Nd, scale_null_found = N, False
    if has_scale and N.shape[1]:
        Nd, scale_null_found, words = _scale_message(N, scale, names, held_scale)
        messages += words
    order = list(range(p)) if priority is None else priority
    directions = _directions(Nd, list(order), names, describe, context) if name else []
    messages += [d.words for d in directions]
    messages += _weak_messages(weak, sv, weak_idx)
    own = sv.U is not None and not lifted and rank == sv.rank  # the null space is the SVD's own
    return Identifiability(names, rank, sv.S, rtol, N, R, identifiable, scale_null_found, tuple(directions),
                           weak, tuple(messages), weak_vectors, naming_basis=Nd,
                           factor=Factor.of(sv.U, sv.S, sv.Vt, sv.c, rank) if own else None)


@dataclass(frozen=True)
class _Spectrum:
    S: np.ndarray  # (p,) singular values of the column-scaled J, descending, zero-padded
    Vt: np.ndarray  # (p, p) right singular vectors in scaled coordinates
    c: np.ndarray  # (p,) column norms (1 where a column is zero)
    smax: float
    rank: int
    U: np.ndarray | None = None  # (m, p) left singular vectors, where J is no taller than 2p (a triangular factor)


def _spectrum(J: np.ndarray, rtol: float, colnorm: np.ndarray | None = None) -> _Spectrum:
    """Singular values and vectors of J with every column scaled to unit norm, and the rank at ``rtol``."""
    m, p = J.shape
    Js, c_safe = unit_columns(J, colnorm)
    U = None
    if p <= m <= 2 * p:  # ``right_svd``'s own call, keeping U
        U, S, Vt = thin_svd(Js)
    else:
        S, Vt = right_svd(Js) if m >= p else svd(Js, full_matrices=True)[1:]  # all p rows of Vt
    S_full = S if len(S) == p else np.concatenate([S, np.zeros(p - len(S))])  # zero-padded when J is wide
    smax = S_full[0] if p else 0.0
    rank = int(np.count_nonzero(S_full > rtol * smax)) if smax > 0 else 0
    return _Spectrum(S_full, Vt, c_safe, smax, rank, U)


def _scale_at_rank(scale: Callable, J: np.ndarray, sv: _Spectrum):
    """(the scale direction ``scale(solve)``, the solve's u in natural units or None). Where the spectrum has
    U, ``solve`` of ``J u = b`` is the minimum-norm solution in scaled coordinates cut at the rank (``V1 S1^-1
    U1^T b``): decided by the data, not by which null singular values round-off leaves above numpy's cut;
    elsewhere (and for any other matrix) numpy's ``lstsq``, as before."""
    if sv.U is None:
        return scale(lstsq), None
    cut, spectrum = [], Factor(sv.U, sv.S, sv.Vt, sv.c, sv.rank)  # its step: the solve cut at the rank

    def solve(A, b):
        if A is not J:
            return lstsq(A, b)
        cut.append(spectrum.step(b))
        return cut[-1]

    d = scale(solve)
    return d, (cut[-1] if cut and d is not None else None)


def _minimum_norm(d: np.ndarray, u: np.ndarray, N0: np.ndarray) -> np.ndarray:
    """``d = s + u`` with u's part along the spectrum's null space ``N0`` (natural units, orthonormal) removed:
    the minimum-norm solution in natural units, what numpy's ``lstsq`` gives where its cut-off cuts every null
    singular value."""
    return d - N0 @ (N0.T @ u)


def hold_exact(Ns: np.ndarray, c: np.ndarray, symmetries: list, has_scale: bool, gauges: np.ndarray | None = None):
    """The scaled null basis ``Ns`` (p, k orthonormal, of the Jacobian with columns scaled by ``c``) with the exact
    gauges of the noise-free problem added (``gauges``, a basis), then the exact symmetries of the cost where
    residuals left lift them out of it (scale without a measured length: shrinking every length shrinks them; the
    rotations of ``held``): (null basis, rank, lifted directions, whether the scale was lifted, whether its first
    columns are ``Ns`` itself)."""
    rank = len(c) - Ns.shape[1]
    lifted, held_scale = [], False
    if gauges is not None and gauges.shape[1]:
        # the null space is the gauges' (noise lifts exact gauges out of Ns, and a direction of Ns at the rank
        # threshold may only tilt towards them); both bases come from round-off-level singular values, so a
        # dimension one lacks has singular value ~1 outside it, a tilt far less. Where none was lifted, Ns is
        # kept as it is: the structure cache (``consistent_nulls``) then gives the same basis without G.
        G = _orth(c[:, None] * gauges)
        lifted += list(_outside(G, Ns).T)
        if lifted:
            Ns = np.column_stack([G, _outside(Ns, G)])
            rank = len(c) - Ns.shape[1]
    spectral = not lifted
    for k, h in enumerate(symmetries):
        hc = c * h
        hc /= norm(hc)
        outside = hc - Ns @ (Ns.T @ hc)
        if norm(outside) > 1e-6:
            Ns = np.column_stack([Ns, outside / norm(outside)])
            rank -= 1
            lifted.append(hc)
            held_scale = held_scale or (has_scale and k == 0)
    return Ns, rank, lifted, held_scale, spectral


def _outside(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Orthonormal directions of span(A) (orthonormal columns) that are new dimensions outside span(B)."""
    if A.shape[1] == 0:
        return A
    U, S, _ = svd(A - B @ (B.T @ A), full_matrices=False)
    return U[:, S > 0.5]


def _weak_indices(sv: _Spectrum, rank: int, rtol: float, weak_rtol: float, lifted) -> np.ndarray:
    S, smax = sv.S, sv.smax
    limit = _weak_limit(S[:rank], weak_rtol) * smax
    if not sv.rank or not S[sv.rank - 1] < limit:  # S descends: the last above rtol is the smallest candidate
        return _NONE
    weak_idx = np.flatnonzero((S > rtol * smax) & (S < limit))
    if lifted:  # directions lifted by the residuals are not weak directions but held
        weak_idx = np.array([i for i in weak_idx if max(abs(sv.Vt[i] @ h) for h in lifted) < 0.5], dtype=int)
    return weak_idx


_NONE = np.zeros(0, dtype=int)
_NONE.flags.writeable = False


def _weak_vectors(sv: _Spectrum, weak_idx: np.ndarray) -> np.ndarray:
    """(p, w) the weak directions in natural units, unit norm; (p, 0) without any (the common case, at once)."""
    if not len(weak_idx):
        return np.zeros((len(sv.c), 0))
    v = sv.Vt[weak_idx].T / sv.c[:, None]
    v /= np.maximum(norms(v, 0), 1e-300)
    return v


def _scale_message(N: np.ndarray, scale: np.ndarray, names, held_scale: bool):
    """(null basis without the scale direction, whether scale is in the null space, its message)."""
    s = scale / np.linalg.norm(scale)
    if np.linalg.norm(N.T @ s) <= 1 - 1e-4:
        return N, False, []
    s = N @ (N.T @ s)
    s /= np.linalg.norm(s)
    lengths = [names[i] for i in np.argsort(-np.abs(s)) if abs(s[i]) > 1e-3 * np.max(np.abs(s))]
    words = (
        "scale cannot be identified: no known length closes the loop, so scaling every length together "
        f"(mostly {_list(lengths, 4)}) leaves every residual unchanged (thesis Sec. 2.11)"
        + (" up to scaling the residuals themselves, which would let the data shrink the robot towards a "
           "point; it is held at its current value" if held_scale else "")
        + "; fix or measure one length"
    )
    return _orth(N - np.outer(s, s @ N), drop=1), True, [words]


# The principal angle (natural units) to which a null basis that ``_directions`` names is taken to be known. The
# SVD gives a null space to about machine precision times sigma_max over the smallest kept singular value (the
# dual arm's: 3e-15 measured against one-ulp changes of the joint readings, with the kept ones above 6e-2 of the
# largest); 1e-10 still holds with the smallest kept singular value near 1e-5 of the largest, below which the
# report calls directions weak.
NAMING_ACCURACY = 1e-10


def _directions(Nd: np.ndarray, order, names, describe, context: str,
                accuracy: float = NAMING_ACCURACY) -> list[Direction]:
    """The null directions in reduced row-echelon form, each named by its pivot in ``order``; a coefficient is
    printed to the digits its uncertainty (``_uncertainty``, for a basis known to the angle ``accuracy``) leaves,
    at most three, and a coordinate is a partner only where it is at least 1e-3 of the row's largest and ten
    times its uncertainty (a coefficient not known to one digit is not claimed)."""
    directions, order = [], np.asarray(order, dtype=int)
    rows = _rref(Nd.T, order)
    if not rows:
        return directions
    R = np.array(rows)
    A = np.abs(R)  # every row at once: pivots, partners by size, the ones worth naming
    pivots = order[np.argmax(A[:, order] > 0.5, axis=1)].tolist()
    # partners by size, equal sizes (to 1e-9 of the row's largest) in layout order: round-off never reorders them
    JS = np.argsort(-np.round(A / A.max(axis=1, keepdims=True) * 1e9), axis=1, kind="stable")
    AJ = np.take_along_axis(A, JS, 1)
    keep = (JS != np.array(pivots)[:, None]) & (AJ > 1e-3 * A.max(axis=1, keepdims=True))
    U = _uncertainty(R, accuracy)
    digits = [None] * len(rows)  # three each, unless some coefficient worth naming holds fewer
    if U is not None:
        UJ = np.take_along_axis(U, JS, 1)
        keep &= AJ >= 10.0 * UJ
        digits = np.clip(np.floor(np.log10(np.maximum(AJ, 1e-300) / np.maximum(UJ, 1e-300))), 1, 3).astype(int)
    for row, piv, js, kept, dg in zip(rows, pivots, JS, keep, digits):
        shown = None if dg is None else dg[kept].tolist()
        js = js[kept].tolist()
        partners = tuple(zip([names[j] for j in js], row[js].tolist()))
        words = f"{names[piv]} cannot be identified{(' from ' + context) if context else ''}"
        if partners:
            words += f": it trades off against {_partner_list(partners, shown)}"
        else:
            words += ": it does not affect any residual"
        extra = describe(row) if describe else ""
        if extra:
            words += f" ({extra})"
        directions.append(Direction(names[piv], partners, row, words))
    return directions


def _uncertainty(R: np.ndarray, accuracy: float) -> np.ndarray | None:
    """(k, p) first-order bounds on how far the echelon rows R (k, p) of a null space move when it turns by the
    angle ``accuracy``: ``accuracy * |R_i| * sqrt(1 + |R[:, j]|^2)``. R^T = N M^-1 (N an orthonormal basis, M its
    pivot rows), so N + N_perp E moves R^T by (I - R^T S) N_perp E M^-1 (S: the pivot rows' selection); column i
    of M^-1 has R_i's norm (N is orthonormal) and row j of (I - R^T S) N_perp that of (I - R^T S), which is
    sqrt(1 + |R[:, j]|^2) off the pivots (0 on them: pivots are exact). None where no bound exceeds 1e-6: every
    coefficient worth naming (1e-3 of its row's largest, which is at least the pivot's 1) then holds three
    digits."""
    R2 = R * R
    rows, cols = np.sqrt(np.add.reduce(R2, axis=1)), np.sqrt(1.0 + np.add.reduce(R2, axis=0))
    if accuracy * float(rows.max()) * float(cols.max()) <= 1e-6:
        return None
    return accuracy * rows[:, None] * cols[None, :]


def _partner_list(partners, digits=None, limit: int = 6) -> str:
    """``_list`` of the partners' words, formatting only those shown, each to its ``digits`` (None: 3 each)."""
    if digits is None:
        shown = [f"{n} ({v:+.3g})" for n, v in partners[:limit]]
    else:
        shown = [f"{n} ({v:+.{d}g})" for (n, v), d in zip(partners[:limit], digits)]
    more = len(partners) - len(shown)
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def _weak_messages(weak, sv: _Spectrum, weak_idx) -> list[str]:
    out = [f"weakly identifiable direction (singular value far below the others; its estimate rests on little "
           f"more than the noise): {w}" for w in weak]
    if len(weak_idx):
        hold = float(f"{1.5 * sv.S[weak_idx].max() / sv.smax:.1g}")
        out.append(f"to hold the {len(weak_idx)} weakly identifiable direction(s) at their current values instead "
                   f"of estimating them, calibrate with rank_rtol={hold:g} (they are then reported as "
                   "unidentifiable), or give priors on the parameters they involve")
    return out


WEAK_GAP = 100.0


def _weak_limit(s: np.ndarray, weak_rtol: float) -> float:
    """Relative singular value below which identifiable directions count as weak (see the module docstring)."""
    if len(s) < 2 or s[0] <= 0 or s[-1] / s[0] >= WEAK_CEILING:  # rel descends: no gap below the ceiling then
        return weak_rtol
    rel = (s / s[0]).tolist()  # Python floats: the same divisions and comparisons, without numpy's calls
    for a, b in zip(rel, rel[1:]):
        if b < WEAK_CEILING and a / max(b, 1e-300) > WEAK_GAP:
            return max(weak_rtol, b * (1 + 1e-12))
    return weak_rtol


def select_columns(J: np.ndarray, order: Sequence[int], rank: int, tol: float = 1e-6) -> list[int]:
    """Greedy column-pivoted QR in a user priority order: the first ``rank`` columns (of unit-scaled J) that
    add a new direction. The others are to be held fixed (the user's gauge)."""
    Js, _ = unit_columns(J)
    Q = np.zeros((J.shape[0], 0))
    chosen: list[int] = []
    for j in order:
        if len(chosen) == rank:
            break
        r = Js[:, j] - Q @ (Q.T @ Js[:, j])
        nr = np.linalg.norm(r)
        if nr > tol:
            Q = np.column_stack([Q, r / nr])
            chosen.append(int(j))
    return sorted(chosen)


def _rref(M: np.ndarray, order: Sequence[int]) -> list[np.ndarray]:
    """Rows spanning the same space as M's rows, reduced with pivots taken in ``order``."""
    M = np.asarray(M, dtype=float)
    k, p = M.shape
    order = np.asarray(order, dtype=int)
    rest = np.setdiff1d(np.arange(p), order)  # columns outside ``order``: reduced too, never pivots
    perm = np.concatenate([order, rest])
    A = M[:, perm]  # columns in pivot order (a copy): ``order[pos:]`` is the slice ``pos:`` (same arithmetic)
    n = len(order)
    rows_done, pos = 0, 0
    while rows_done < k and pos < n:
        # the next column in order with a usable pivot (the columns passed over stay unusable: A is unchanged)
        usable = np.flatnonzero(np.abs(A[rows_done:, pos:n]).max(axis=0) >= 1e-8)
        if not len(usable):
            break
        j = pos + int(usable[0])
        pos = j + 1
        i = rows_done + int(np.argmax(np.abs(A[rows_done:, j])))
        if i != rows_done:
            A[[rows_done, i]] = A[[i, rows_done]]
        A[rows_done] /= A[rows_done, j]
        pivot = A[rows_done].copy()  # eliminate column j from every row, then put the pivot row back
        A -= np.outer(A[:, j], pivot)
        A[rows_done] = pivot
        rows_done += 1
    A[np.abs(A) < 1e-12] = 0.0
    out = np.empty((rows_done, p))
    out[:, perm] = A[:rows_done]
    return list(out)


def _orth(A: np.ndarray, drop: int = 0) -> np.ndarray:
    if A.shape[1] == 0:
        return A
    U, S, _ = svd(A, full_matrices=False)
    k = A.shape[1] - drop
    return U[:, :k]


def _top_names(v: np.ndarray, names, count: int = 4) -> str:
    idx = np.argsort(-np.abs(v))[:count]
    return " ".join(f"{v[i]:+.2f} {names[i]}" for i in idx)


def _list(items: Sequence[str], limit: int = 6) -> str:
    items = list(items)
    if len(items) <= limit:
        return ", ".join(items)
    return ", ".join(items[:limit]) + f" and {len(items) - limit} more"
