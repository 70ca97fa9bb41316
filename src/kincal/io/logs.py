"""Controller logs: motor radians in controller channel order -> arm radians in model order.

Frida's ExtCtrl logs (thesis Sec. 3.3 "Logging") hold motor radians, one column per controller channel, in
the controller's joint numbering, every 0.004032 s. ``motor_to_joint`` divides by the gear ratios
(thesis Table 3.1, incl. the -101 of the wrist joint in the tilt house) and reorders with the model's
``controller_order`` (channel c carries model joint ``controller_order[c]``). ``standstill`` finds samples
where every joint stands still (for tracker measurements); ``downsample`` keeps every k-th sample.

Log file (CSV, one header line; ``#`` lines are comments): optional ``t`` column (s), then for each arm
``<arm>.c1 .. <arm>.cN``, the motor angle (rad) of controller channel 1..N. Without a header
(``header=False``) every column is a channel, arms in the order given, with a fixed sample period.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from kincal.errors import DataFormatError, ShapeError
from kincal.io import units
from kincal.io.atomic import output_file
from kincal.io.yamlfile import read_text
from kincal.kinematics import ArmModel, Robot


EXTCTRL_PERIOD_S = 0.004032


def motor_to_joint(motor: np.ndarray, model: ArmModel) -> np.ndarray:
    """Motor radians (N, n) in controller channel order -> joint readings (N, n) in model order."""
    motor = np.asarray(motor, dtype=float)
    if motor.ndim != 2 or motor.shape[1] != model.dof:
        raise ShapeError(f"motor log of arm '{model.name}': expected shape (N, {model.dof}), got {motor.shape}")
    q = np.empty_like(motor)
    order = np.asarray(model.controller_order)
    q[:, order] = motor / model.gear_ratios[order]
    return q


def joint_to_motor(q: np.ndarray, model: ArmModel) -> np.ndarray:
    """Inverse of ``motor_to_joint``: joint readings (N, n) -> motor radians in controller channel order."""
    q = np.asarray(q, dtype=float)
    order = np.asarray(model.controller_order)
    return q[:, order] * model.gear_ratios[order]


def standstill(t: np.ndarray, q: np.ndarray, threshold: float, window: int) -> np.ndarray:
    """Mask (N,) of samples where the joint speed |dq/dt| of every joint stays below ``threshold`` (rad/s)
    over a centred window of ``window`` samples."""
    q = np.asarray(q, dtype=float)
    t = np.asarray(t, dtype=float)
    if len(q) < 2:
        return np.ones(len(q), dtype=bool)
    speed = np.max(np.abs(np.gradient(q, t, axis=0)), axis=1)
    fast = (speed >= threshold).astype(float)
    w = min(max(int(window), 1), len(fast))  # a window longer than the log is the whole log
    # any fast sample within the window -> not still
    near_fast = np.convolve(fast, np.ones(w), mode="same") > 0
    return ~near_fast


def stops(mask: np.ndarray) -> list[slice]:
    """Runs of consecutive True samples of a standstill mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(int)))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2])]


def downsample(n: int, every: int) -> np.ndarray:
    """Indices of every ``every``-th of n samples, starting with the first."""
    if every < 1:
        raise ShapeError(f"downsample: every must be >= 1, got {every}")
    return np.arange(0, n, every)


def read_motor_log(path, robot: Robot, arms: tuple[str, ...], *, header: bool = True,
                   period_s: float = EXTCTRL_PERIOD_S) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a motor-radian log: (t (N,), {arm: motor (N, n) in controller channel order})."""
    return _read_log(path, robot, arms, header, period_s)[:2]


def _read_log(path, robot: Robot, arms: tuple[str, ...], header: bool, period_s: float):
    """``read_motor_log`` and the file's line number of each sample."""
    path = Path(path)
    lines = read_text(path, "log").splitlines()
    sizes = [robot[a].dof for a in arms]
    rows, head, head_line = [], None, 0
    delim = "," if any("," in ln for ln in lines[:5]) else None
    for number, line in enumerate(lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f.strip() for f in (next(csv.reader([s])) if delim else s.split())]
        if header and head is None:
            head, head_line = fields, number
            continue
        rows.append((number, fields))
    if header:
        if head is None:
            raise DataFormatError(f"{path}: no header line")
        want = [f"{a}.c{k + 1}" for a, n in zip(arms, sizes) for k in range(n)]
        for c in want:
            if c not in head:
                raise DataFormatError(f"{path}: line {head_line}, column '{c}': missing from the header; "
                                      f"found {', '.join(head)}")
        cols = (["t"] if "t" in head else []) + want
        index = [head.index(c) for c in cols]
    else:
        cols = [f"{a}.c{k + 1}" for a, n in zip(arms, sizes) for k in range(n)]
        index = list(range(len(cols)))
    width = len(head) if header else len(cols)
    data = np.empty((len(rows), len(cols)))
    for r, (number, fields) in enumerate(rows):
        if len(fields) != width:
            raise DataFormatError(f"{path}: line {number}: expected {width} values, found {len(fields)}")
        for k, i in enumerate(index):
            x = units.plain_number(fields[i])
            if x is None:
                raise DataFormatError(f"{path}: line {number}, column '{cols[k]}': expected a finite number, "
                                      f"found {fields[i][:40]!r}")
            data[r, k] = x
    if not len(rows):
        raise DataFormatError(f"{path}: no samples")
    if cols[0] == "t":
        t, data = data[:, 0], data[:, 1:]
        _check_times(path, t, [number for number, _ in rows])
    else:
        t = np.arange(len(rows)) * period_s
    out, k = {}, 0
    for a, n in zip(arms, sizes):
        out[a] = data[:, k:k + n]
        k += n
    return t, out, [number for number, _ in rows]


def convert_log(path, robot: Robot, arms: tuple[str, ...], *, every: int = 1, still_rad_s: float | None = None,
                window: int = 25, per_stop: bool = False, header: bool = True,
                period_s: float = EXTCTRL_PERIOD_S,
                model: str | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a motor log and return (t, {arm: joint readings in model order}).

    ``still_rad_s`` keeps only samples where every joint of every arm moves slower than that over
    ``window`` samples; ``per_stop`` then reduces each stop to its mean. ``every`` downsamples what is left.
    ``model``: where ``robot`` was read from, for messages (default its name). Times must increase strictly;
    gear ratios must have a plausible size (``GEAR_RATIO_RANGE``); a joint reading that overflows is refused.
    """
    _check_options(path, still_rad_s, window, every, period_s)
    _check_gear_ratios(robot, arms, model)
    t, motor, lines = _read_log(path, robot, arms, header, period_s)
    with np.errstate(over="ignore", invalid="ignore"):  # refused just below, with the line
        q = {a: motor_to_joint(m, robot[a]) for a, m in motor.items()}
    _check_finite(path, q, robot, lines)
    if still_rad_s is not None:
        mask = standstill(t, np.concatenate([q[a] for a in arms], axis=1), still_rad_s, window)
        if not mask.any():
            raise DataFormatError(f"{path}: no sample is still (every joint slower than {still_rad_s:g} rad/s over "
                                  f"{window} samples); expected at least one stop: raise --still-rad-s")
        if per_stop:
            runs = stops(mask)
            t = np.array([t[s].mean() for s in runs])
            q = {a: np.array([v[s].mean(axis=0) for s in runs]).reshape(len(runs), -1) for a, v in q.items()}
        else:
            t, q = t[mask], {a: v[mask] for a, v in q.items()}
    keep = downsample(len(t), every)
    return t[keep], {a: v[keep] for a, v in q.items()}


def _check_options(path, still_rad_s, window, every, period_s) -> None:
    """The conversion options are numbers that make sense (one-line errors naming the option)."""
    def positive(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) and x > 0

    for name, value in (("--still-rad-s", still_rad_s), ("--period-s", period_s)):
        if value is not None and not positive(value):
            raise DataFormatError(f"{path}: option {name}: expected a finite number > 0, found {value!r}")
    for name, value in (("--window", window), ("--every", every)):
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            raise DataFormatError(f"{path}: option {name}: expected an integer >= 1, found {value!r}")


# Magnitudes of a gear ratio (motor turns per joint turn) that a real drive can have: direct drives are 1,
# harmonic and cycloidal gears reach a few hundred, belt stages on top a few thousand.
GEAR_RATIO_RANGE = (1e-3, 1e5)


def _check_gear_ratios(robot: Robot, arms, model: str | None) -> None:
    """A ratio like 1e-320 divides the motor angles into infinity: refuse it, naming the model field."""
    low, high = GEAR_RATIO_RANGE
    for a in arms:
        arm = robot[a]
        for j, ratio in enumerate(arm.gear_ratios):
            if not (np.isfinite(ratio) and low <= abs(ratio) <= high):
                raise DataFormatError(
                    f"model {model or robot.name!r}: arms.{a}.joints[{j}].gear_ratio (joint '{arm.joint_names[j]}'):"
                    f" expected a magnitude between {low:g} and {high:g}, found {float(ratio)!r}")


def _check_times(path, t: np.ndarray, lines: list[int]) -> None:
    """Times of a log increase strictly: a repeated time made the joint speed infinite and merged stops."""
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise DataFormatError(f"{path}: line {lines[i]}, column 't': expected a time after {float(t[i - 1])!r} s "
                              f"(line {lines[i - 1]}), found {float(t[i])!r} s; times must increase strictly")


def _check_finite(path, q: dict[str, np.ndarray], robot: Robot, lines: list[int]) -> None:
    """A huge motor angle over a small gear ratio overflows: refuse it rather than write ``inf``."""
    for a, v in q.items():
        bad = np.argwhere(~np.isfinite(v))
        if len(bad):
            i, j = (int(x) for x in bad[0])
            ratio = float(robot[a].gear_ratios[j])
            raise DataFormatError(f"{path}: line {lines[i]}, arm '{a}', joint '{robot[a].joint_names[j]}': the motor "
                                  f"angle divided by the gear ratio {ratio!r} is not a finite number")


def write_joint_csv(path, t: np.ndarray, q: dict[str, np.ndarray], robot: Robot, *, overwrite: bool = False) -> Path:
    """CSV with ``t`` and ``<arm>.<joint>`` columns (rad, model order): the joint part of a data set file.
    Written all or nothing (``kincal.io.atomic``): an interrupted run leaves no cut-off or half-replaced file."""
    path = Path(path)
    with output_file(path, overwrite=overwrite) as temp, open(temp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t"] + [f"{a}.{j}" for a in q for j in robot[a].joint_names])
        for i in range(len(t)):
            w.writerow([repr(float(t[i]))] + [repr(float(x)) for a in q for x in q[a][i]])
    return path
