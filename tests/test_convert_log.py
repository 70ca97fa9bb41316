"""Controller logs: motor radians in controller order -> arm radians in model order; standstill; CLI."""

import numpy as np
import pytest

from kincal.cli import main
from kincal.errors import DataFormatError
from kincal.io.logs import (
    EXTCTRL_PERIOD_S,
    convert_log,
    joint_to_motor,
    motor_to_joint,
    standstill,
    stops,
)
from kincal.io.models import load_robot, save_robot
from kincal.robots import load


@pytest.fixture(scope="module")
def frida():
    return load("frida")


def trajectory(n_stops=4, move=250, hold=200):
    """A known arm-radian path of both arms: smooth moves between random poses, holding still in between."""
    rng = np.random.default_rng(0)
    poses = rng.uniform(-0.8, 0.8, (n_stops + 1, 14))
    segs = []
    for k in range(n_stops):
        s = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, move))[:, None]
        segs += [poses[k] + s * (poses[k + 1] - poses[k]), np.repeat(poses[k + 1][None], hold, axis=0)]
    q = np.concatenate(segs)
    return np.arange(len(q)) * EXTCTRL_PERIOD_S, q, poses[1:]


def write_log(path, t, q, frida):
    motor = {a: joint_to_motor(q[:, 7 * i: 7 * i + 7], frida[a]) for i, a in enumerate(("left", "right"))}
    header = ["t"] + [f"{a}.c{k}" for a in motor for k in range(1, 8)]
    rows = np.concatenate([t[:, None], motor["left"], motor["right"]], axis=1)
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    return motor


def test_frida_gear_ratios_and_controller_order(frida):
    arm = frida["right"]
    q = np.arange(1.0, 8.0)[None] / 100  # j1..j7 = 0.01 .. 0.07 rad
    motor = joint_to_motor(q, arm)
    # channel c carries model joint controller_order[c]; motor = ratio * joint (Table 3.1, -101 on j5)
    for c, j in enumerate(arm.controller_order):
        assert motor[0, c] == pytest.approx(arm.gear_ratios[j] * q[0, j])
    assert -101.0 in arm.gear_ratios
    np.testing.assert_allclose(motor_to_joint(motor, arm), q, rtol=0, atol=1e-15)


def test_convert_a_synthetic_motor_log(tmp_path, frida):
    t, q, _ = trajectory()
    write_log(tmp_path / "log.csv", t, q, frida)
    t2, out = convert_log(tmp_path / "log.csv", frida, ("left", "right"), every=10)
    np.testing.assert_allclose(t2, t[::10])
    np.testing.assert_allclose(out["left"], q[::10, :7], atol=1e-13)
    np.testing.assert_allclose(out["right"], q[::10, 7:], atol=1e-13)


def test_standstill_keeps_only_the_stops(tmp_path, frida):
    t, q, stop_poses = trajectory()
    mask = standstill(t, q, threshold=1e-3, window=25)
    runs = stops(mask)
    assert len(runs) == len(stop_poses)
    for r, pose in zip(runs, stop_poses):
        np.testing.assert_allclose(q[r], np.repeat(pose[None], r.stop - r.start, axis=0))
    write_log(tmp_path / "log.csv", t, q, frida)
    _, out = convert_log(tmp_path / "log.csv", frida, ("left", "right"), still_rad_s=1e-3, per_stop=True)
    np.testing.assert_allclose(out["left"], stop_poses[:, :7], atol=1e-12)


def test_cli_convert_log(tmp_path, frida):
    t, q, stop_poses = trajectory()
    write_log(tmp_path / "log.csv", t, q, frida)
    out = tmp_path / "joints.csv"
    rc = main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-a", "left", "-a", "right", "-o", str(out),
               "--still-rad-s", "0.001", "--per-stop"])
    assert rc == 0
    lines = out.read_text().splitlines()
    assert lines[0].split(",")[:3] == ["t", "left.j1", "left.j2"] and len(lines) == 1 + len(stop_poses)
    values = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    np.testing.assert_allclose(values[:, 1:], stop_poses, atol=1e-12)
    assert main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-o", str(out)]) == 2  # no overwrite
    assert main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-o", str(tmp_path / "log.csv"),
                 "--overwrite"]) == 2  # never the input


def test_headerless_log_and_errors(tmp_path, frida):
    t, q, _ = trajectory(n_stops=1, move=20, hold=5)
    motor = joint_to_motor(q[:, 7:], frida["right"])
    (tmp_path / "raw.txt").write_text("\n".join(" ".join(repr(float(x)) for x in r) for r in motor) + "\n")
    t2, out = convert_log(tmp_path / "raw.txt", frida, ("right",), header=False)
    np.testing.assert_allclose(out["right"], q[:, 7:], atol=1e-13)
    np.testing.assert_allclose(t2, np.arange(len(q)) * EXTCTRL_PERIOD_S)
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(DataFormatError, match="line 1: expected 7 values, found 3"):
        convert_log(tmp_path / "bad.txt", frida, ("right",), header=False)


# ------------------------------------------------------------------ issue #10: silent wrong results of convert-log


def test_repeated_timestamps_are_refused_naming_the_line(tmp_path, frida, capsys):
    """A log whose clock repeats every time (each time written twice) divided by zero and found one stop
    instead of ten: it is refused with the first repeated time's line, by the library and by the CLI."""
    t, q, _ = trajectory(n_stops=10, move=40, hold=40)
    t = np.repeat(t[::2], 2)[:len(t)]  # 0, 0, 2p, 2p, ...
    write_log(tmp_path / "log.csv", t, q, frida)
    with pytest.raises(DataFormatError, match=r"log\.csv: line 3, column 't': expected a time after 0\.0 s "
                                              r"\(line 2\), found 0\.0 s; times must increase strictly"):
        convert_log(tmp_path / "log.csv", frida, ("left", "right"), still_rad_s=1e-3, per_stop=True)
    out = tmp_path / "q.csv"
    assert main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "line 3, column 't'" in err and not out.exists()


def test_a_time_going_back_is_refused_after_comments(tmp_path, frida):
    t, q, _ = trajectory(n_stops=1, move=20, hold=5)
    t[7] = t[3]
    write_log(tmp_path / "log.csv", t, q, frida)
    text = (tmp_path / "log.csv").read_text().splitlines()
    (tmp_path / "log.csv").write_text("\n".join(["# exported by ExtCtrl", *text]) + "\n")  # line numbers shift by 1
    with pytest.raises(DataFormatError, match=r"line 10, column 't': expected a time after .* \(line 9\)"):
        convert_log(tmp_path / "log.csv", frida, ("left", "right"))


def test_ten_distinct_stops_are_found_when_times_increase(tmp_path, frida):
    """The counterpart of the repeated-times case: the same log with a clean clock yields its ten stops."""
    t, q, stop_poses = trajectory(n_stops=10, move=40, hold=40)
    write_log(tmp_path / "log.csv", t, q, frida)
    _, out = convert_log(tmp_path / "log.csv", frida, ("left", "right"), still_rad_s=1e-3, per_stop=True)
    assert len(out["left"]) == 10
    np.testing.assert_allclose(out["left"], stop_poses[:, :7], atol=1e-12)


def _model_with_ratio(tmp_path, ratio):
    ur = load("ur10")
    arm = ur["arm"]
    ratios = np.array(arm.gear_ratios, dtype=float)
    ratios[2] = ratio
    return save_robot(ur.replace_arm("arm", arm.replace(gear_ratios=ratios)), tmp_path / "ur_ratio.yaml")


def _ur_log(tmp_path):
    log = tmp_path / "ur_log.csv"
    log.write_text("t," + ",".join(f"arm.c{i + 1}" for i in range(6)) + "\n"
                   + "\n".join(f"{0.004 * k}," + ",".join(f"{0.01 * k * (i + 1)}" for i in range(6))
                               for k in range(1, 30)) + "\n")
    return log


@pytest.mark.parametrize("ratio", [1e-320, 1e-9, 1e12])
def test_an_implausible_gear_ratio_is_refused_naming_the_model_field(tmp_path, capsys, ratio):
    """A gear ratio of 1e-320 wrote 'inf' joint readings: refused, naming the model and the joint's field."""
    model = _model_with_ratio(tmp_path, ratio)
    out = tmp_path / "q.csv"
    assert main(["convert-log", str(_ur_log(tmp_path)), "-m", str(model), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(model) in err and "arms.arm.joints[2].gear_ratio" in err
    assert f"found {ratio!r}" in err and "expected a magnitude between 0.001 and 100000" in err
    assert not out.exists()


def test_a_reading_that_overflows_is_refused_not_written_as_inf(tmp_path):
    model = load_robot(str(_model_with_ratio(tmp_path, 1e-3)))
    log = _ur_log(tmp_path)
    lines = log.read_text().splitlines()
    cells = lines[5].split(",")
    cells[3] = "1e307"  # channel 3 carries the joint of ratio 1e-3 (UR: controller order is the model's)
    lines[5] = ",".join(cells)
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"ur_log\.csv: line 6, arm 'arm', joint '.*': the motor angle divided "
                                              r"by the gear ratio 0\.001 is not a finite number"):
        convert_log(log, model, ("arm",))


def test_convert_log_never_leaves_a_partial_file(tmp_path, frida, monkeypatch):
    """The CSV is written to a temporary beside it and renamed at the end: a failure while writing leaves
    nothing new, and --overwrite keeps the old file until the new one is complete."""
    import kincal.io.logs as logs

    t, q, _ = trajectory(n_stops=1, move=20, hold=5)
    write_log(tmp_path / "log.csv", t, q, frida)
    out = tmp_path / "joints.csv"
    out.write_text("old\n")
    real = logs.csv.writer

    def failing_writer(fh, **kw):
        w = real(fh, **kw)
        w.writerow(["partial"])
        raise KeyboardInterrupt

    monkeypatch.setattr(logs.csv, "writer", failing_writer)
    assert main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-o", str(out), "--overwrite"]) == 130
    assert out.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["joints.csv", "log.csv"]
    monkeypatch.setattr(logs.csv, "writer", real)
    assert main(["convert-log", str(tmp_path / "log.csv"), "-m", "frida", "-o", str(out), "--overwrite"]) == 0
    assert out.read_text().startswith("t,right.j1,")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["joints.csv", "log.csv"]
