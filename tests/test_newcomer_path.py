"""The newcomer's path, all from the command line (issue #12): import a URDF, simulate, calibrate, report,
export the calibration into the URDF, compensate a program; each output checked."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.cli import main
from kincal.io.models import load_robot
from kincal.io.programs import read_program
from kincal.kinematics import forward_kinematics
from kincal.simulate import random_configurations

pytest.importorskip("yourdfpy")
pytest.importorskip("matplotlib")
from kincal.io.urdf import from_urdf  # noqa: E402
from test_export import URDF  # noqa: E402

SCENARIO = """format: kincal-scenario
version: 1
name: testarm-tracker
model: model.yaml
seed: 3
units: {length: mm, angle: deg}
truth: {level: fine}
experiment: {kind: pose, n: 80, known_tracker: true}
noise: {position_mm: 0.02, orientation_deg: 0.002}
validation: 100
output: {angle: deg, length: mm}
"""
JOB = """format: kincal-job
version: 1
model: model.yaml
data: [sim/data.yaml]
validation: [sim/validation/arm.yaml]
free: kinematic
"""


def _run(*args) -> int:
    return main([str(a) for a in args])


def test_import_simulate_calibrate_report_export_compensate(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "arm.urdf").write_text(URDF)
    assert _run("import", "arm.urdf", "--base-link", "base_link", "--tip-link", "tool0", "-o", "model.yaml") == 0
    (tmp_path / "scenario.yaml").write_text(SCENARIO)
    assert _run("simulate", "scenario.yaml", "-o", "sim", "--quiet") == 0
    (tmp_path / "job.yaml").write_text(JOB)
    assert _run("calibrate", "job.yaml", "-o", "result", "--quiet") in (0, 5)
    assert _run("report", "result") == 0
    html = (tmp_path / "result" / "report.html").read_text()
    assert "Predicted accuracy over the workspace" in html and "data:image/png;base64," in html
    assert _run("export", "result/model.yaml", "--to", "urdf", "-o", "calibrated.urdf") == 0
    calibrated = load_robot(tmp_path / "result" / "model.yaml")["arm"]
    back = from_urdf(tmp_path / "calibrated.urdf", "base_link", "tool0")
    q = random_configurations(calibrated, 100, np.random.default_rng(0))
    assert np.abs(forward_kinematics(back, q) - forward_kinematics(calibrated, q)).max() < 1e-12
    nominal = load_robot(tmp_path / "model.yaml")["arm"]
    program = random_configurations(nominal, 30, np.random.default_rng(1), 0.1)
    header = ",".join(f"arm.{j}" for j in nominal.joint_names)
    np.savetxt(tmp_path / "program.csv", np.degrees(program), delimiter=",", header=header, comments="")
    code = _run("compensate", "result/model.yaml", "program.csv", "--nominal", "model.yaml", "--angle", "deg",
                "-o", "compensated.csv")
    assert code in (0, 1)
    out = (tmp_path / "compensated.csv").read_text().splitlines()
    assert out[0].split(",")[-1] == "arm.status" and len(out) == 31
    ok = np.array([line.endswith(",ok") for line in out[1:]])
    assert ok.mean() > 0.8
    values = np.array([[float(x) for x in line.split(",")[:3]] for line in out[1:]])  # the first joints
    assert values.shape == (30, 3)
    comp = np.radians(np.array([[float(x) for x in line.split(",")[: nominal.dof]] for line in out[1:]]))
    reached = forward_kinematics(calibrated, comp[ok])[:, :3, 3]  # three joints: the tool point is compensated
    np.testing.assert_allclose(reached, forward_kinematics(nominal, program[ok])[:, :3, 3], atol=1e-6)


def test_compensate_reads_controller_order_and_refuses_bad_programs(tmp_path, capsys):
    (tmp_path / "p.csv").write_text("right.ch1,right.ch2\n1,2\n")
    assert _run("compensate", "frida", tmp_path / "p.csv", "--nominal", "frida", "-o", tmp_path / "o.csv") == 2
    assert "missing from the header" in capsys.readouterr().err
    (tmp_path / "q.csv").write_text("left.j1\n1\n")
    assert _run("compensate", "frida", tmp_path / "q.csv", "--nominal", "frida", "-o", tmp_path / "o.csv") == 2
    assert "missing from the header" in capsys.readouterr().err
    frida = load_robot("frida")
    m = frida["right"]
    q = random_configurations(m, 5, np.random.default_rng(2), 0.1)
    from kincal.io.logs import joint_to_motor
    motor = joint_to_motor(q, m)
    header = ",".join(f"right.ch{c + 1}" for c in range(7))
    np.savetxt(tmp_path / "c.csv", motor, delimiter=",", header=header, comments="")
    prog = read_program(tmp_path / "c.csv", frida)
    assert prog.form == "controller"
    np.testing.assert_allclose(prog.q["right"], q)
    assert _run("compensate", "frida", tmp_path / "c.csv", "--nominal", "frida", "-o", tmp_path / "c_out.csv") == 0
    out = np.loadtxt(tmp_path / "c_out.csv", delimiter=",", skiprows=1, usecols=range(7))
    np.testing.assert_allclose(out, motor, atol=1e-6)  # the same robot: nothing to compensate
