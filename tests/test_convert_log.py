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
