"""DH table files (issue #12): ``kincal export --to dh|mdh`` writes them, ``kincal import`` reads them back
into a model file with the same forward kinematics; bad tables give one line naming file, row and field."""

from __future__ import annotations

import numpy as np
import pytest

from kincal import robots
from kincal.cli import main
from kincal.errors import DataFormatError
from kincal.io.dh_table import dh_table_robot
from kincal.io.models import load_robot, save_robot
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.simulate import perturb_robot


def _q(arm, n=200, seed=0):
    return np.random.default_rng(seed).uniform(np.maximum(arm.lower, -3), np.minimum(arm.upper, 3), (n, arm.dof))


def _models():
    """Nominal UR10, Panda and Frida's right arm, and a calibrated Panda with a moved base and a tool."""
    panda = perturb_robot(robots.load("panda"), "fine", rng=2)["arm"]
    panda = panda.replace(base=se3.exp(np.array([0.1, -0.2, 0.3, 0.01, 0.02, 0.3])),
                          tool=se3.exp(np.array([0.0, 0.01, 0.12, 0.0, 0.1, 0.0])))
    return {"ur10": robots.load("ur10")["arm"], "panda": robots.load("panda")["arm"],
            "frida": robots.load("frida")["right"], "panda_calibrated": panda}


@pytest.mark.parametrize("fmt", ["dh", "mdh"])
def test_export_then_import_gives_the_same_forward_kinematics(fmt, tmp_path, capsys):
    for label, arm in _models().items():
        model = tmp_path / f"{label}.yaml"
        save_robot(Robot(label, {"arm": arm.replace(name="arm")}), model)
        table = tmp_path / f"{label}_{fmt}.yaml"
        back_file = tmp_path / f"{label}_{fmt}_back.yaml"
        assert main(["export", str(model), "--to", fmt, "-o", str(table)]) == 0
        assert main(["import", str(table), "-o", str(back_file)]) == 0
        back = load_robot(back_file)["arm"]
        q = _q(arm)
        assert np.abs(forward_kinematics(back, q) - forward_kinematics(arm, q)).max() < 1e-9, label
        assert back.joint_names == arm.joint_names
        assert np.array_equal(back.lower, arm.lower) and np.array_equal(back.upper, arm.upper)
    assert "wrote" in capsys.readouterr().out


def test_hand_written_table_in_mm_and_deg():
    """The UR10's published table, written by hand in mm and deg, gives the built-in UR10 (its flange frame)."""
    rows = [(0, 90, 127.3), (-612, 0, 0), (-572.3, 0, 0), (0, 90, 163.941), (0, -90, 115.7), (0, 0, 92.2)]
    data = {"format": "kincal-dh", "convention": "standard",
            "joints": [{"joint": n, "a_mm": a, "alpha_deg": al, "d_mm": d, "theta_deg": 0, "limits": [-360, 360]}
                       for n, (a, al, d) in zip(robots.load("ur10")["arm"].joint_names, rows)]}
    arm = dh_table_robot(data, "ur10_dh.yaml", "ur10")["arm"]
    ur10 = robots.load("ur10")["arm"]
    q = _q(ur10)
    assert np.abs(forward_kinematics(arm, q) - forward_kinematics(ur10, q)).max() < 1e-12
    assert np.allclose(arm.upper, np.radians(360))


BAD = [
    ({"joints": [{"a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0}]}, r"t\.yaml: \(top level\): missing key 'format'"),
    ({"format": "kincal-dh", "convention": "dh", "joints": []}, r"t\.yaml: convention: expected one of standard, modified"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0},
                                                                  {"a_m": "x", "alpha_rad": 0, "d_m": 0, "theta_rad": 0}]},
     r"t\.yaml: joints row 2\.a_m: expected a number, found str 'x'"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "a_mm": 0, "alpha_rad": 0, "d_m": 0,
                                                                   "theta_rad": 0}]},
     r"t\.yaml: joints row 1: expected one of a_m, a_mm \(found a_m, a_mm\)"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "d_m": 0, "theta_rad": 0}]},
     r"t\.yaml: joints row 1: expected one of alpha_rad, alpha_deg \(found none\)"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0,
                                                                   "limits": [1, -1]}]},
     r"t\.yaml: joints row 1\.limits: expected lower < upper"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0,
                                                                   "offset": 1}]},
     r"t\.yaml: joints row 1\.offset: unknown key 'offset'"),
    ({"format": "kincal-dh", "convention": "standard", "joints": [{"a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0}],
      "flange": [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
     r"t\.yaml: flange\.matrix: rotation is not orthonormal"),
    ({"format": "kincal-dh", "convention": "standard",
      "joints": [{"joint": "j", "a_m": 0, "alpha_rad": 0, "d_m": 0, "theta_rad": 0}] * 2},
     r"t\.yaml: joints: .*distinct"),
]


@pytest.mark.parametrize("data, message", BAD)
def test_bad_tables_name_file_row_and_field(data, message):
    with pytest.raises(DataFormatError, match=message):
        dh_table_robot(data, "t.yaml", "t")


def test_cli_bad_table_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: kincal-dh\nconvention: standard\njoints:\n  - {a_m: 0, alpha_rad: 0, d_m: 0, theta_rad: 0}\n"
                   "  - {a_m: 0, alpha_rad: zero, d_m: 0, theta_rad: 0}\n")
    assert main(["import", str(bad), "-o", str(tmp_path / "m.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.yaml: joints row 2.alpha_rad: expected a number" in err
    assert not (tmp_path / "m.yaml").exists()
    assert main(["import", str(tmp_path / "robot.urdf"), "-o", str(tmp_path / "m.yaml")]) == 2
    assert "needs --base-link and --tip-link" in capsys.readouterr().err
