"""kincal on the real data sets in ../shared/datasets: the table of docs/real-data.md.

For each tracker data set (pose, markers): the fit on every configuration (residual RMS, rank, variance factor,
outer iterations, wall time) and k-fold held-out errors (calibrate on k-1 folds, predict the held-out fold with
the calibrated arm and the tracker/markers estimated from the training folds). For the MUKCa sockets: offsets
trained on three plate placements, consistency on the other six (spread of the predicted ball centre about its
per-socket mean, distance between the two socket means against 50 mm), next to the nominal and the authors'
calibrated URDF. Loaders and held-out helpers live in tests/ (realdata.py, holdout.py). Absent data sets are
skipped with a note. ``--honest``: only the table of docs/real-data.md "Honest prediction" (k-fold held-out
RMS against the RMS predicted from each fold's training fit, ``kincal.estimation.crossval``).

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/real_data.py [--folds 6] [--honest] [--justin]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS (see bench_calibrate.py)

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import holdout as ho  # noqa: E402
import realdata as rd  # noqa: E402

from kincal.estimation import FrameDistance, calibrate, evaluate  # noqa: E402

MM, DEG = 1e-3, np.pi / 180


def _fmt(x, scale, digits=3):
    return "-" if x is None else f"{x / scale:.{digits}f}"


def tracker_row(label, robot, ds, free, noise, folds, published="", **options):
    t = time.perf_counter()
    res = calibrate(robot, [ds], free, noise=noise, **options)
    wall = time.perf_counter() - t
    cv = ho.cross_validate(robot, ds, free, k=folds, noise=noise, **options).summary()
    a = res.after[0]
    free_name = free if isinstance(free, str) else ("+".join(free) or "frames only")
    cells = [label, free_name + (f" ({options['loss']})" if "loss" in options else ""), str(ds.size),
             f"{res.identifiability.rank}/{len(res.identifiability.names)}", str(res.iterations), f"{wall:.2f}",
             _fmt(a.position_rms, MM), _fmt(a.orientation_rms, DEG), f"{res.sigma2:.2f}",
             _fmt(cv["pos_mean"], MM), _fmt(cv["pos_rms"], MM), _fmt(cv["pos_max"], MM),
             _fmt(cv.get("ori_rms"), DEG), res.status, published]
    return cells


def mukca_rows(path):
    nominal = rd.mukca_robot(path)
    authors = rd.mukca_robot(path, "calibrated_urdf/panda_2/panda.urdf")
    train = [d for pl in rd.MUKCA_TRAIN for d in rd.mukca_sockets(path, "panda_2", pl)]
    t = time.perf_counter()
    res = calibrate(nominal, train, "offsets", noise=rd.NOISE["mukca"])
    wall = time.perf_counter() - t
    held = [rd.mukca_sockets(path, "panda_2", pl) for pl in rd.mukca_placements(path, "panda_2")
            if pl not in rd.MUKCA_TRAIN]
    cons = [FrameDistance(f"{pl}.hole0.socket", f"{pl}.hole1.socket", rd.MUKCA_HOLE_DISTANCE, 1e-4)
            for pl in rd.MUKCA_TRAIN]
    t = time.perf_counter()
    kin = calibrate(nominal, train, "kinematic", noise=rd.NOISE["mukca"], constraints=cons)
    wall_kin = time.perf_counter() - t
    rows = []
    for label, robot in (("nominal URDF", nominal), ("kincal offsets", res.robot),
                         ("kincal kinematic + 50 mm", kin.robot), ("authors' URDF", authors)):
        out = [ho.socket_consistency(robot["arm"], s) for s in held]
        spread = np.concatenate([s for s, _ in out])
        dist = np.array([d for _, d in out]) - rd.MUKCA_HOLE_DISTANCE
        rows.append([label, _fmt(spread.mean(), MM), _fmt(spread.max(), MM), _fmt(np.abs(dist).max(), MM)])
    fit = max(a.position_rms for a in res.after)
    print(f"\nMUKCa panda_2: offsets trained on {', '.join(rd.MUKCA_TRAIN)} ({sum(d.size for d in train)} "
          f"configurations, 12 sockets): {res.status}, rank {res.identifiability.rank}/"
          f"{len(res.identifiability.names)}, {res.iterations} iterations, {wall:.2f} s, fit RMS up to "
          f"{fit / MM:.3f} mm per socket, variance factor {res.sigma2:.2f}; level kinematic with the 50 mm between "
          f"the holes of each placement (FrameDistance, sigma 0.1 mm): {kin.status}, rank {kin.identifiability.rank}/"
          f"{len(kin.identifiability.names)}, {wall_kin:.2f} s, variance factor {kin.sigma2:.2f}")
    _table(["model", "held-out spread mean mm", "max mm", "max |d - 50 mm| mm"], rows)


def motoman_rows(path):
    """Self-contact (distance) calibration of the right arm on a 70/30 split, the same offsets on the laser
    tracker, and plane contacts (each surface an unknown plane) checked on the self-contact data."""
    robot, ds = rd.motoman_robot(), rd.motoman_self_touch(path)
    order = np.random.default_rng(0).permutation(ds.size)
    train, test = ds.subset(order[: int(0.7 * ds.size)]), ds.subset(order[int(0.7 * ds.size):])
    planes = [rd.motoman_plane(path, f"{s}{k}") for s in ("higher_table", "lower_table", "wall_table") for k in "12"]
    leica = rd.motoman_robot("leica")
    tracker = rd.motoman_leica(path)
    rows = [["nominal", "-", "-", "-", "-", _fmt(evaluate(robot, [train])[0].position_rms, MM),
             _fmt(evaluate(robot, [test])[0].position_rms, MM), _fmt(evaluate(robot, [ds])[0].position_rms, MM),
             _fmt(evaluate(leica, [tracker])[0].position_rms, MM), "1.36 / 1.31"]]
    for label, data, ref in (("self-touch (train)", [train], "0.95 / 1.02"), ("planes (6 surfaces)", planes, "")):
        t = time.perf_counter()
        res = calibrate(robot, data, rd.MOTOMAN_FREE, noise=rd.NOISE["motoman"])
        wall = time.perf_counter() - t
        on_leica = leica.replace_arm("right", leica["right"].replace(offsets=res.robot["right"].offsets))
        fit = np.sqrt(np.mean([a.position_rms ** 2 for a in res.after]))
        rows.append([label, f"{res.identifiability.rank}/{len(res.identifiability.names)}", str(res.iterations),
                     f"{wall:.2f}", _fmt(fit, MM), _fmt(evaluate(res.robot, [train])[0].position_rms, MM),
                     _fmt(evaluate(res.robot, [test])[0].position_rms, MM),
                     _fmt(evaluate(res.robot, [ds])[0].position_rms, MM),
                     _fmt(evaluate(on_leica, [tracker])[0].position_rms, MM), ref])
    print(f"\nMotoman: right arm {', '.join(rd.MOTOMAN_FREE)} free; self-touch distance RMS (mm) on the 70/30 split "
          f"({train.size}/{test.size} poses) and Leica reflector RMS with the same offsets ({tracker.size} poses, "
          "tracker fitted); authors: train / test RMS")
    _table(["calibrated from", "rank", "it", "s", "fit RMS", "self-touch train", "test", "all", "Leica RMS",
            "authors"], rows)


def honest_rows(folds: int):
    """One row per case of ``realdata.HONEST_CASES``: k-fold held-out RMS (outlying rows left out, and with
    them) against the RMS predicted from each fold's training fit alone, and their ratio."""
    rows = []
    for name, make in rd.HONEST_CASES.items():
        try:
            robot, ds, free, noise = make()
        except rd.DataMissing as exc:
            print(f"skipped {name}: {exc}")
            continue
        t = time.perf_counter()
        cv = ho.honest_prediction(robot, ds, free, k=folds, noise=noise)
        pos, ori = cv.pooled("position"), cv.pooled("orientation")
        free_name = free if isinstance(free, str) else "L, U, R, B offsets + tool"
        vf = np.array([f.sigma2 for f in cv.folds])
        rows.append([name, free_name, str(ds.size), f"{vf.min():.2f}-{vf.max():.2f}", _fmt(pos.rms, MM),
                     _fmt(pos.rms_predicted, MM), f"{pos.rms / pos.rms_predicted:.2f}",
                     f"{pos.flagged}", _fmt(pos.rms_all, MM), f"{pos.rms_all / pos.rms_predicted:.2f}",
                     f"{ori.rms / ori.rms_predicted:.2f}" if ori.groups else "-", _fmt(cv.position_model, MM),
                     f"{time.perf_counter() - t:.1f}"])
    print(f"Honest prediction: {folds}-fold held-out position RMS (mm; frames from the training folds, nothing "
          "refitted) against the RMS predicted from each fold's training fit alone")
    _table(["data", "free", "N", "var factor (folds)", "held-out RMS", "predicted", "ratio", "outlying rows",
            "RMS with them", "ratio with them", "orientation ratio", "cv model error", "s"], rows)


def justin_rows(path, folds: int = 5):
    """Agile Justin as a tree (torso once, both arms on it, the coupled torso joint declared): fit on all 500
    poses and k-fold held-out errors of both hand markers (mean / std / max mm) at each level of the paper; the
    compliant levels loaded by the robot's own weight, geometry and compliances in one solve
    (``realdata.justin_elastic_case``)."""
    robot, sets = rd.justin_robot(path), rd.justin_markers(path)
    rows = [_justin_row(label, robot, list(sets), free, published, folds, noise=rd.JUSTIN_NOISE, outliers="keep")
            for label, (free, published) in rd.JUSTIN_LEVELS.items()]
    for label, published in rd.JUSTIN_ELASTIC.items():
        robot, sets, options = rd.justin_elastic_case(path, label)
        free = options.pop("free")
        rows.append(_justin_row(label, robot, sets, free, published, folds, **options))
    print(f"\nDLR Agile Justin: two hand markers, 500 poses; fit on all and {folds}-fold held-out (mm)")
    _table(["level", "rank", "it", "s", "fit mean / std / max", "held-out mean / std / max", "paper (fit)",
            "status"], rows)


def _justin_row(label, robot, sets, free, published, folds, **options):
    t = time.perf_counter()
    res = calibrate(robot, sets, free, **options)
    wall = time.perf_counter() - t
    fit = np.concatenate([ho.prediction_errors(res, d)[0] for d in sets])
    held = ho.cross_validate(robot, sets, free, k=folds, **options).position
    return [label, f"{res.identifiability.rank}/{len(res.identifiability.names)}", str(res.iterations),
            f"{wall:.2f}", _mean_std_max(fit), _mean_std_max(held), " / ".join(map(str, published)), res.status]


def _mean_std_max(e):
    return " / ".join(f"{x / MM:.2f}" for x in (e.mean(), e.std(), e.max()))


def _table(header, rows):
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, ["-" * w for w in widths], *rows]:
        print(" | ".join(str(c).ljust(w) for c, w in zip(r, widths)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folds", type=int, default=6)
    ap.add_argument("--honest", action="store_true", help="only the honest-prediction table")
    ap.add_argument("--justin", action="store_true", help="only the Agile Justin table (5-fold unless --folds)")
    args = ap.parse_args(argv)
    k = args.folds
    if args.honest:
        honest_rows(k)
        return
    if args.justin:
        justin_rows(rd.folder(rd.JUSTIN), 5 if "--folds" not in (argv or sys.argv) else k)
        return
    rows = []

    def attempt(name, make):
        try:
            rows.extend(make())
        except rd.DataMissing as exc:
            print(f"skipped {name}: {exc}")

    def wu():
        p = rd.folder(rd.WU)
        robot, mk, pose = rd.wu_robot(p), rd.wu_markers(p), rd.wu_pose(p)
        return [tracker_row("wu markers", robot, mk, [], rd.NOISE["wu"], k, "nominal 18.17 / 30.50"),
                tracker_row("wu markers", robot, mk, "offsets", rd.NOISE["wu"], k),
                tracker_row("wu markers", robot, mk, "kinematic", rd.NOISE["wu"], k, "MOP 0.266 / 0.525, TOP 0.569 / 1.235"),
                tracker_row("wu frames", robot, pose, "kinematic", rd.NOISE["wu"], k, "MFP 0.692 / 1.336, TFP 0.788 / 1.515")]

    def ur10():
        robot, ds = rd.figaroh_ur10(rd.folder(rd.FIGAROH) / "ur10")
        return [tracker_row("ur10e camera", robot, ds, ["arm.home"], rd.NOISE["ur10"], k, "fit: about 3.2 mean"),
                tracker_row("ur10e camera", robot, ds, "kinematic", rd.NOISE["ur10"], k),
                tracker_row("ur10e camera", robot, ds, "kinematic", rd.NOISE["ur10"], k, loss="soft_l1", f_scale=2.0)]

    def mocap():
        out = []
        for label, make, ref in (("talos marker", rd.figaroh_talos, "fit: 5.2 RMS"),
                                 ("tiago 3 markers", rd.figaroh_tiago, "fit: 3.3-4.0 mean")):
            robot, ds = make(rd.folder(rd.FIGAROH) / label.split()[0])
            out += [tracker_row(label, robot, ds, [], rd.NOISE["mocap"], k, ref),
                    tracker_row(label, robot, ds, "offsets", rd.NOISE["mocap"], k),
                    tracker_row(label, robot, ds, "kinematic", rd.NOISE["mocap"], k)]
        return out

    for name, make in (("wu2015-irb120-poe", wu), ("figaroh ur10", ur10), ("figaroh talos/tiago", mocap)):
        attempt(name, make)
    print(f"Tracker data: fit on every configuration, then {k}-fold held-out errors (mm, deg); published: mean / max mm")
    _table(["data", "free", "N", "rank", "it", "s", "fit pos RMS", "fit ori RMS", "var factor", "held-out mean",
            "RMS", "max", "ori RMS", "status", "published / reference"], rows)
    for name, rows_of in ((rd.MUKCA, mukca_rows), (rd.MOTOMAN, motoman_rows), (rd.JUSTIN, justin_rows)):
        try:
            rows_of(rd.folder(name))
        except rd.DataMissing as exc:
            print(f"skipped {name}: {exc}")


if __name__ == "__main__":
    main()
