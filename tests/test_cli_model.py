"""``kincal model show`` and ``kincal fk``: output content and one-line errors with non-zero exit codes."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from kincal import robots
from kincal.cli import cli, main
from kincal.io import save_robot
from kincal.lie.rotations import rpy_to_matrix
from kincal.kinematics import forward_kinematics


def _run(*args):
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.output


def test_model_show_table_lists_joints_screws_and_poses():
    out = _run("model", "show", "frida", "--arm", "right")
    assert "frida / right: 7 joints" in out and "left" not in out.split("controller order")[0]
    assert "(-0.3565, 0, 0.0405, 0, 1, 0)" in out  # j4 twist, thesis Table 4.8
    assert "(0.0405, 0, 0.3565)" in out  # j4 point, Table A.1
    assert "-143.50 .. 43.50 deg" in out and "-101" in out
    assert "controller order (channel 1..n -> joint): j1, j2, j4, j5, j6, j7, j3" in out
    assert "home  T_base_flange(0): xyz (0.3375, 0.0000, 0.4105) m, rpy (0.000, 90.000, 0.000) deg" in out


def test_model_show_json_of_a_file(tmp_path):
    path = save_robot(robots.load("ur10"), tmp_path / "ur10_copy.yaml")
    data = json.loads(_run("model", "show", str(path), "--json"))
    arm = data["arms"]["arm"]
    assert data["name"] == "ur10" and arm["dof"] == 6
    assert arm["joints"][2]["name"] == "elbow" and arm["joints"][2]["lower_deg"] == pytest.approx(-360)
    np.testing.assert_allclose(arm["joints"][1]["axis"], [0, -1, 0])
    np.testing.assert_allclose(arm["home"]["xyz_m"], [-1.1843, -0.256141, 0.0116])  # UR CB3 table (issue #12)


def test_fk_deg_and_rad_agree_with_library():
    q_deg = [10, -20, 30, -40, 50, -60, 70]
    model = robots.load("frida")["left"]
    T = forward_kinematics(model, np.radians(q_deg))
    text = _run("fk", "frida", "--arm", "left", "--q-deg", ",".join(map(str, q_deg)))
    assert f"({T[0, 3]:.6f}, {T[1, 3]:.6f}, {T[2, 3]:.6f})" in text
    assert "rpy [deg]" in text and "quaternion wxyz" in text
    data = json.loads(_run("fk", "frida", "--arm", "left", "--q-rad", " ".join(map(str, np.radians(q_deg))), "--json"))
    np.testing.assert_allclose(data["matrix"], T, atol=1e-12)
    np.testing.assert_allclose(rpy_to_matrix(np.radians(data["rpy_deg"])), T[:3, :3], atol=1e-12)
    w, x, y, z = data["quaternion_wxyz"]
    assert w >= 0 and abs(np.hypot(np.hypot(w, x), np.hypot(y, z)) - 1) < 1e-12


def test_fk_single_arm_needs_no_arm_option():
    data = json.loads(_run("fk", "klimchik3r", "--q-rad", "0,0,0", "--json"))
    np.testing.assert_allclose(data["xyz_m"], [1.4, 0, 1.0])


@pytest.mark.parametrize(
    "args,message",
    [
        (["fk", "ur10", "--q-deg", "0,0,0,0,0"],
         "has 6 joints (shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2, wrist_3); got 5 values"),
        (["fk", "yumi", "--q-deg", "0"],
         "no built-in robot of that name (built-in robots: dual7_torso, frida, klimchik3r, kr270, panda, ur10)"),
        (["fk", "frida", "--arm", "middle", "--q-deg", "0,0,0,0,0,0,0"],
         "robot 'frida' has no arm 'middle'; arms: right, left"),
        (["fk", "frida", "--q-deg", "0,0,0,0,0,0,0"], "robot 'frida' has several arms (right, left); choose one"),
        (["model", "show", "frida", "--arm", "middle"], "has no arm 'middle'"),
    ],
)
def test_errors_are_one_line_with_nonzero_exit(capsys, args, message):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("kincal: error: ") and message in err


def test_fk_requires_exactly_one_unit(capsys):
    assert main(["fk", "ur10"]) != 0
    assert "exactly one of --q-deg or --q-rad" in capsys.readouterr().err
    assert main(["fk", "ur10", "--q-deg", "0", "--q-rad", "0"]) != 0
    assert main(["fk", "ur10", "--q-deg", "a,b"]) != 0
    assert "expected numbers" in capsys.readouterr().err


def test_model_show_prints_joint_compliance(tmp_path):
    r = robots.load("klimchik3r")
    arm = r["arm"] if "arm" in r.arms else r[next(iter(r.arms))]
    key = next(k for k in r.arms if r[k] is arm)
    path = save_robot(r.replace_arm(key, arm.replace(compliance=np.array([0.0, 2.5e-6, 1e-6]))), tmp_path / "c.yaml")
    out = _run("model", "show", str(path))
    assert "joint compliance:" in out and "2.5e-06 rad/(N m)" in out
    assert "joint compliance" not in _run("model", "show", "klimchik3r")
    data = json.loads(_run("model", "show", str(path), "--json"))
    assert data["arms"][key]["joints"][1]["compliance_rad_per_Nm"] == pytest.approx(2.5e-6)
