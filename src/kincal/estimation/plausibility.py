"""Data implausible for the robot, found before any solve: degrees declared as radians, metres as mm, a single
absurd measured value (1e300 in one cell); and joint readings past the model's limits (a warning). After the
solve: estimates no real robot has (a joint compliance below 0).

A solve on such data grinds towards an arm shrunk or grown 1000 times (or cannot fit at all, or overflows) and
can take minutes; the data loaders (``kincal.io.datasets``, naming file, line and column) and ``solve`` (naming
the data set and field) refuse it first. A negative compliance is kept in the calibrated model as estimated (the
model must predict what the solver fitted) and reported: within ``NEGATIVE_SIGMAS`` standard deviations of 0 as
a warning (a stiff joint's estimate scatters around 0), beyond them as a reason not to trust the result.
"""

from __future__ import annotations

import hashlib
import math
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from kincal.data import Dataset
from kincal.estimation.stats import mean
from kincal.kinematics import PRISMATIC, Robot
from kincal.kinematics.tree import tip_pose
from kincal.params import COMPLIANCE, LATERAL, Layout
from kincal.schema import LENGTH, SCHEMAS

# A reading of a revolute joint with limits beyond this (rad) is not an angle in radians (a continuous joint,
# without limits, may turn any number of times); measured points whose spread differs from the nominal tool's
# at the same readings (a mounted arm's through its carriers) by more than SPREAD_FACTOR (either way) are not in
# the stated length unit, judged on data sets of one arm, only where the tool moves at least MIN_TOOL_SPREAD (m)
# and on at most SPREAD_ROWS rows spread over the data.
MAX_JOINT_RAD = 4 * math.pi
SPREAD_FACTOR = 30.0
MIN_TOOL_SPREAD = 0.01
SPREAD_ROWS = 4000
# One measured coordinate farther than CELL_FACTOR times the data's size (the larger of the tool's spread, the
# measured points' median distance from their median, and MIN_SIZE m) from its column's median is no
# measurement: named by its row before it is judged as a spread (it would dominate the RMS) or solved.
CELL_FACTOR = 100.0
MIN_SIZE = 1.0


@dataclass(frozen=True)
class Implausible:
    """What is implausible: a joint reading (``field`` "q": ``arm``, ``sample``, ``joint`` index, ``value`` rad),
    one measured value (``field`` its key, ``sample``, ``column`` its index among the entry's coordinates,
    ``value`` in m, ``spread`` the largest distance from the median allowed) or a measured entry's spread
    (``field`` its key, ``value`` the ratio to the nominal tool's, ``spread`` and ``tool`` in m)."""

    field: str
    arm: str
    value: float
    sample: int = -1
    joint: int = -1
    spread: float = 0.0
    tool: float = 0.0
    column: int = -1

    def describe(self, robot: Robot) -> str:
        if self.field == "q":
            return (f"joint '{self.arm}.{robot[self.arm].joint_names[self.joint]}' reads {self.value:.6g} rad, "
                    f"beyond +-4 pi: not an angle in radians")
        if self.column >= 0:
            return (f"the measured {self.field} of sample {self.sample} reads {self.value:.6g} m, more than "
                    f"{self.spread:.4g} m from the median of its column ({CELL_FACTOR:g} times the data's size): not "
                    "a measurement")
        return (f"the measured {self.field} spread over {self.spread * 1e3:.4g} mm RMS where the nominal "
                f"{robot.name} tool moves {self.tool * 1e3:.4g} mm RMS at these joint readings "
                f"({self.value:.3g} times): not in the stated length unit")


def implausible_units(robot: Robot, ds: Dataset) -> Implausible | None:
    """The first implausible joint reading, measured value or measured spread of ``ds`` for ``robot``, or None."""
    bad, tool = readings_verdict(robot, ds)
    if bad is not None:
        return bad
    a = ds.arms[0]
    lengths = _measured_lengths(ds)
    for key, x in lengths.items():
        bad = _absurd_cell(key, a, x, tool)
        if bad is not None:
            return bad
    if tool < MIN_TOOL_SPREAD:
        return None
    for key, x in lengths.items():
        if len(x) > SPREAD_ROWS or not x.flags.c_contiguous:  # else every row, laid out as the copy would be
            x = x[_spread_rows(len(x))]
        ratio = spread(x) / tool
        if not 1 / SPREAD_FACTOR <= ratio <= SPREAD_FACTOR:
            return Implausible(key, a, ratio, spread=spread(x), tool=tool)
    return None


# What ``implausible_units`` finds from the joint readings alone (a reading beyond +-4 pi, the nominal tool's
# spread): a Monte Carlo study checks the same readings with fresh measurements at every repeat. Keyed by the
# robot object (a weak reference: robots are immutable; a dead one's id never matches) and a digest of the data
# set's arms and readings; the newest READINGS_ENTRIES kept.
READINGS_ENTRIES = 64
_READINGS: OrderedDict[tuple, tuple[weakref.ref, Implausible | None, float]] = OrderedDict()
_READINGS_LOCK = threading.Lock()


def readings_verdict(robot: Robot, ds: Dataset) -> tuple[Implausible | None, float]:
    """(the first joint reading of ``ds`` beyond +-4 pi rad, or None; the nominal tool's RMS spread at the readings
    of a one-arm data set, else 0), remembered per robot and readings."""
    key = (id(robot), _readings_digest(ds))
    with _READINGS_LOCK:  # a Dask worker may run tasks on several threads
        hit = _READINGS.get(key)
        if hit is not None and hit[0]() is robot:
            _READINGS.move_to_end(key)
            return hit[1], hit[2]
    bad = _bad_reading(robot, ds)
    tool = _tool_spread(robot, ds) if bad is None and len(ds.arms) == 1 else 0.0
    with _READINGS_LOCK:
        _READINGS[key] = (weakref.ref(robot), bad, tool)
        while len(_READINGS) > READINGS_ENTRIES:
            _READINGS.popitem(last=False)
    return bad, tool


def clear_readings_cache() -> None:
    """Forget ``readings_verdict``'s memory (tests, cold-start timings)."""
    with _READINGS_LOCK:
        _READINGS.clear()


def _readings_digest(ds: Dataset) -> bytes:
    """A digest of the data set's arms (in order) and every arm's joint readings with their shapes."""
    h = hashlib.blake2b(repr((ds.arms, [(a, q.shape) for a, q in ds.q.items()])).encode(), digest_size=20)
    for q in ds.q.values():
        h.update(np.ascontiguousarray(q, dtype=float).tobytes())
    return h.digest()


def _bad_reading(robot: Robot, ds: Dataset) -> Implausible | None:
    """The first reading of a revolute joint with limits beyond +-4 pi rad (not an angle in radians), or None."""
    for a, q in ds.q.items():
        arm = robot[a]
        limited = np.isfinite(arm.lower) | np.isfinite(arm.upper)
        checked = np.array([t != PRISMATIC for t in arm.joint_types]) & limited
        big = np.abs(q) * checked > MAX_JOINT_RAD
        if big.any():
            i, j = np.argwhere(big)[0]
            return Implausible("q", a, float(q[i, j]), int(i), int(j))
    return None


def past_limits(robot: Robot, q_by_arm: dict) -> list[tuple[str, int, np.ndarray, float]]:
    """Joint readings (arm -> (N, dof)) past the model's limits: per arm and joint with any, (arm, joint index,
    the samples, the limit the first of them is past)."""
    out = []
    for a, q in q_by_arm.items():
        arm = robot[a]
        for j in range(arm.dof):
            rows = np.flatnonzero((q[:, j] < arm.lower[j]) | (q[:, j] > arm.upper[j]))
            if len(rows):
                first = q[rows[0], j]
                out.append((a, j, rows, float(arm.lower[j] if first < arm.lower[j] else arm.upper[j])))
    return out


def _tool_spread(robot: Robot, ds: Dataset) -> float:
    """RMS spread (m) of the nominal tool of the data set's one arm at its readings: through its carriers (the
    composite chain) when mounted; 0 (not judged) when the data lack a carrier's readings."""
    a = ds.arms[0]
    line = robot.lineage(a)
    if not all(s in ds.q for s in line):
        return 0.0
    rows = _spread_rows(ds.size)
    return spread(tip_pose(robot, a, {s: ds.q[s][rows] for s in line})[:, :3, 3])


@lru_cache(maxsize=16)
def _spread_rows(n: int) -> np.ndarray:
    """At most SPREAD_ROWS row indices spread evenly over ``n`` rows (a spread needs no more); read-only,
    remembered per ``n``."""
    rows = np.unique(np.linspace(0, n - 1, min(n, SPREAD_ROWS)).astype(int))
    rows.flags.writeable = False
    return rows


def _measured_lengths(ds: Dataset) -> dict[str, np.ndarray]:
    """The measured positions of ``ds`` (m), (N, ..., 3): pose translations and points in a length unit."""
    out = {}
    for f in SCHEMAS[ds.kind].measured:
        if f.key in ds.measured and (f.form == "pose" or (f.form == "points" and f.unit == LENGTH)):
            out[f.key] = ds.measured[f.key][:, :3, 3] if f.form == "pose" else ds.measured[f.key]
    return out


def _absurd_cell(key: str, arm: str, x: np.ndarray, tool: float) -> Implausible | None:
    """The first coordinate of ``x`` (N, ..., 3) farther from its column's median than CELL_FACTOR times the
    data's size, or None."""
    flat = x.reshape(len(x), -1)
    if _within(flat, CELL_FACTOR * MIN_SIZE):  # no cell that far from any value of its column: none from the median
        return None
    median = np.median(flat, axis=0)
    with np.errstate(over="ignore", invalid="ignore"):  # the absurd value itself overflows a distance: inf
        typical = np.median(np.linalg.norm((flat - median).reshape(len(x), -1, 3), axis=-1))
        bound = CELL_FACTOR * max(tool, float(typical), MIN_SIZE)
        far = ~(np.abs(flat - median) <= bound)
    if not far.any():
        return None
    i, c = np.argwhere(far)[0]
    return Implausible(key, arm, float(flat[i, c]), sample=int(i), spread=bound, column=int(c))


def _within(flat: np.ndarray, bound: float) -> bool:
    """Every column of ``flat`` spans at most ``bound`` and holds no value near overflow (a median of two values
    then stays between them): every value is within ``bound`` of its column's median, in floating point too.
    Every |hi| and |lo| within 1e300 is ``max(hi) <= 1e300 and min(lo) >= -1e300`` (lo <= hi; a nan fails both);
    the span is taken last, of such columns only: it cannot overflow (no errstate needed)."""
    hi, lo = flat.max(axis=0), flat.min(axis=0)
    if len(hi) <= _FEW_COLUMNS:  # the same tests on Python floats (a nan fails each), without numpy's calls
        hi, lo = hi.tolist(), lo.tolist()
        return all(h <= 1e300 for h in hi) and all(v >= -1e300 for v in lo) and all(
            h - v <= bound for h, v in zip(hi, lo))
    return bool(hi.max(initial=-np.inf) <= 1e300 and lo.min(initial=np.inf) >= -1e300 and (hi - lo <= bound).all())


_FEW_COLUMNS = 48


def spread(x: np.ndarray) -> float:
    """RMS distance of points (N, ..., 3) from their mean over the samples (numpy's reductions without their
    wrappers, ``stats.mean``; ``math.sqrt`` and ``np.sqrt`` both round correctly)."""
    d = x - mean(x, 0)
    return math.sqrt(mean(np.add.reduce(d * d, axis=-1)))


# A compliance estimated more than this many standard deviations below 0 is no chance scatter of a stiff joint:
# the loads (their size or sign, one not modelled such as gravity) or the model do not fit the data.
NEGATIVE_SIGMAS = 3.0
# A compliance between this (rad/Nm or m/N; 1e-9 rad or m under 1000 N m or N) and 0 is 0 up to round-off (a
# rigid joint fitted to noise-free data), not reported: realistic compliances are 1e-7 and more.
ROUND_OFF_COMPLIANCE = 1e-12


@dataclass(frozen=True)
class NegativeCompliance:
    """A compliance coordinate estimated below 0: its name, value and standard deviation (nan: undetermined)
    in ``unit`` (rad/Nm or m/N)."""

    name: str
    value: float
    std: float
    unit: str

    @property
    def significant(self) -> bool:
        """More than ``NEGATIVE_SIGMAS`` standard deviations below 0 (or undetermined): not noise."""
        return not self.value >= -NEGATIVE_SIGMAS * self.std

    def describe(self) -> str:
        spread = f"std {self.std:.2g}" if np.isfinite(self.std) else "undetermined by the data: no std"
        return f"{self.name} = {self.value:.3g} {self.unit} ({spread})"


def negative_compliances(layout: Layout, estimates) -> tuple[NegativeCompliance, ...]:
    """The compliance ``estimates`` (``kincal.estimation.result.Estimate``; joint and lateral) below 0 (below
    ``-ROUND_OFF_COMPLIANCE``), in layout order."""
    below = [e for e in estimates if e.value < -ROUND_OFF_COMPLIANCE]
    if not below:  # the usual case: no compliance names needed
        return ()
    names = {layout.names[i] for b in layout.blocks if b.kind in (COMPLIANCE, LATERAL)
             for i in range(b.start, b.stop)}
    return tuple(NegativeCompliance(e.name, e.value, e.std, e.unit) for e in below if e.name in names)


def negative_compliance_notes(found) -> list[str]:
    """One line for the compliances below 0 by more than ``NEGATIVE_SIGMAS`` std (the result is not trusted),
    one for those within the noise (a warning)."""
    far = [c.describe() for c in found if c.significant]
    near = [c.describe() for c in found if not c.significant]
    notes = []
    if far:
        notes.append(f"not trusted: compliance estimated below 0 by more than {NEGATIVE_SIGMAS:g} std: "
                     f"{'; '.join(far)}; no joint yields against its load, so the loads (their size or sign, a load "
                     "not modelled such as gravity) or the model do not fit the data; the calibrated model keeps the "
                     "estimate as fitted (exit code 5)")
    if near:
        notes.append(f"warning: compliance estimated below 0 within {NEGATIVE_SIGMAS:g} std of 0 (a stiff joint's "
                     f"estimate scattering around 0): {'; '.join(near)}; kept as estimated in the calibrated model")
    return notes
