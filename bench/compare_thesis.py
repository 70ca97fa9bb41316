"""The thesis' own algorithms next to kincal's estimator, on the same seeded, noise-free Frida data.

For every case: per-joint offset error (estimate - truth, mrad) of each method, the iterations, the accuracy
on 100 fresh random configurations of the true robot (Eval_error: mean tool position error, mm, and mean
rotation error, mrad), and the time.
``u`` marks a parameter kincal reports as unidentifiable (it then stays at its nominal value).
The kinematic case (Table 4.8) lists, per joint, the largest error of the 6 twist coordinates instead
(1e-3 m or mrad), and the home twist (T_st) as a 7th column.

Run: python bench/compare_thesis.py            (about 15 s on one core)
"""

from __future__ import annotations

import time

import numpy as np

from kincal import robots
from kincal.baselines import thesis as th
from kincal.data import Dataset
from kincal.estimation import calibrate
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3, so3
from kincal.simulate import generate_clamp, generate_dual, generate_plate, perturb_robot

OFFSETS = np.array([0.02, -0.03, -0.02, 0.03, 0.015, 0.04, 0.018])  # thesis Tables 4.1-4.7, rad
# Table 4.14: 1 cm along x and y, -1 cm along z, -0.1 rad about x, +0.1 rad about y and z.
CLAMP_ERROR = se3.make(so3.exp(np.array([-0.1, 0.1, 0.1])), np.array([0.01, 0.01, -0.01]))


def forget(ds: Dataset, key: str) -> Dataset:
    known = {k: v for k, v in ds.known.items() if k != key}
    return Dataset(ds.kind, ds.robot, ds.arms, dict(ds.q), dict(ds.measured), known, ds.name, dict(ds.meta))


def with_known(ds: Dataset, key: str, value) -> Dataset:
    return Dataset(ds.kind, ds.robot, ds.arms, dict(ds.q), dict(ds.measured), {**ds.known, key: value}, ds.name,
                   dict(ds.meta))


def accuracy(robot: Robot, validation: dict, arm: str) -> str:
    """Mean tool position error (mm) and rotation error (mrad) on the validation configurations (Eval_error)."""
    v = validation[arm]
    trans, rot = th.eval_error(forward_kinematics(robot[arm], v.q[arm]), v.measured["T_tracker_tool"])
    return f"{trans * 1e3:.3f} / {rot * 1e3:.3f}"


def fmt(x: float, signed: bool = True) -> str:
    x = round(float(x), 3) or 0.0  # no "-0.000"
    return f"{x:+.3f}" if signed else f"{x:.3f}"


def offset_cells(est: np.ndarray, true: np.ndarray, flags=None) -> list[str]:
    flags = [True] * len(est) if flags is None else flags
    return [fmt((e - t) * 1e3) + ("" if ok else " u") for e, t, ok in zip(est, true, flags)]


def kincal_flags(result, arm: str, names) -> list[bool]:
    return [result.estimate(f"{arm}.{j}.offset").identifiable for j in names]


def twist_cells(model, true) -> list[str]:
    per_joint = np.abs(model.screws - true.screws).max(axis=1)
    home = np.abs(model.home_twist() - true.home_twist()).max()
    return [fmt(e * 1e3, False) for e in per_joint] + [fmt(home * 1e3, False)]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def offset_case(rows, label, nominal, truth_robot, ds, validation, arms, baseline, kincal_sets, kincal_free="offsets"):
    base, t_b = timed(baseline)
    for a in arms:
        rows.append([label, "thesis", a, base.iterations_label,
                     *offset_cells(base.offsets[a], truth_robot[a].offsets),
                     accuracy(Robot("x", base.models), validation, a), f"{t_b:.2f}"])
    res, t_k = timed(lambda: calibrate(nominal, kincal_sets, kincal_free))
    for a in arms:
        rows.append([label, "kincal", a, f"{res.iterations} outer",
                     *offset_cells(res.robot[a].offsets, truth_robot[a].offsets,
                                   kincal_flags(res, a, nominal[a].joint_names)),
                     accuracy(res.robot, validation, a), f"{t_k:.2f}"])


def main() -> None:
    frida = robots.load("frida")
    true = frida.replace_arm("left", frida["left"].replace(offsets=OFFSETS)).replace_arm(
        "right", frida["right"].replace(offsets=OFFSETS))
    rows: list[list[str]] = []

    ds, _, val = generate_clamp(true, "left", n=50, rng=0, known_fixture=True)
    offset_case(rows, "clamp, fixture known (T4.1)", frida, true, ds, val, ("left",),
                lambda: th.run("single_offsets", ds, frida), [ds])
    unknown = forget(ds, "T_world_fixture")
    offset_case(rows, "clamp, fixture unknown (T4.2)", frida, true, unknown, val, ("left",),
                lambda: th.run("single_offsets", unknown, frida), [unknown])

    ds, _, val = generate_plate(true, "left", n=80, rng=0)
    offset_case(rows, "plate, 4 fixtures (T4.4)", frida, true, ds, val, ("left",),
                lambda: th.run("several_points", ds, frida), [ds])

    ds, truth, val = generate_dual(true, n=100, rng=0)
    both = ("left", "right")
    offset_case(rows, "dual, clamp known (T4.5)", frida, true, ds, val, both,
                lambda: th.run("dual_offsets", ds, frida), [ds])
    offset_case(rows, "dual, clamp known, factor 1.5 (T4.7)", frida, true, ds, val, both,
                lambda: th.run("dual_offsets", ds, frida, accept_factor=1.5), [ds])
    wrong = truth.values["T_toolA_toolB"] @ CLAMP_ERROR
    offset_case(rows, "dual, clamp off 1 cm/0.1 rad (T4.14)", frida, true, ds, val, both,
                lambda: th.run("dual_offsets", ds, frida, T_toolA_toolB=wrong),
                [with_known(ds, "T_toolA_toolB", wrong)], kincal_free=["offsets", "clamp"])
    no_clamp = forget(ds, "T_toolA_toolB")
    offset_case(rows, "dual, clamp unknown (eq. 3.8)", frida, true, no_clamp, val, both,
                lambda: th.run("dual_offsets", no_clamp, frida), [no_clamp])

    print("| case | method | arm | iterations | " + " | ".join(f"j{i} mrad" for i in range(1, 8))
          + " | accuracy mm / mrad | time s |")
    print("|" + " --- |" * 13)
    for r in rows:
        print("| " + " | ".join(r) + " |")

    kin_true = perturb_robot(frida, "thesis", rng=0, arms=("right",), offset_rad=0.0)
    ds, _, val = generate_dual(kin_true, n=100, rng=0)
    start = frida.replace_arm("left", kin_true["left"])
    base, t_b = timed(lambda: th.run("dual_kinematic", ds, start, known="left"))
    res, t_k = timed(lambda: calibrate(start, [ds], ["right.j*.xi.*", "right.home"]))
    print()
    print("| case | method | iterations | " + " | ".join(f"xi_{i}" for i in range(1, 8))
          + " | xi_st | accuracy mm / mrad | time s |")
    print("|" + " --- |" * 13)
    label = "one arm known, kinematic errors (T4.8)"
    print(f"| {label} | nominal | - | " + " | ".join(twist_cells(frida['right'], kin_true['right']))
          + f" | {accuracy(frida, val, 'right')} | - |")
    print(f"| {label} | thesis | {base.iterations_label} | "
          + " | ".join(twist_cells(base.models['right'], kin_true['right']))
          + f" | {accuracy(Robot('x', base.models), val, 'right')} | {t_b:.2f} |")
    print(f"| {label} | kincal | {res.iterations} outer | "
          + " | ".join(twist_cells(res.robot['right'], kin_true['right']))
          + f" | {accuracy(res.robot, val, 'right')} | {t_k:.2f} |")


if __name__ == "__main__":
    main()
