"""``kincal simulate``: shipped scenarios parse; a small scenario writes data, truth and validation."""

from importlib import resources

import numpy as np
import pytest

from kincal.cli import main
from kincal.errors import DataFormatError
from kincal.io.datasets import load_dataset, load_scenario, read_truth_values
from kincal.simulate.ik import closure_error
from kincal.io.models import read_robot

SHIPPED = sorted(f.name for f in resources.files("kincal.scenarios").iterdir() if f.name.endswith(".yaml"))


def test_shipped_scenarios_parse():
    assert {"frida_clamp_one.yaml", "frida_plate4.yaml", "frida_dual_bracket.yaml",
            "ur10_tracker_markers.yaml"} <= set(SHIPPED)
    kinds = set()
    for name in SHIPPED:
        with resources.as_file(resources.files("kincal.scenarios") / name) as path:
            kinds.add(load_scenario(path)["kind"])
    assert {"clamp", "plate", "dual", "markers"} <= kinds


SMALL_DUAL = """\
format: kincal-scenario
version: 1
name: tiny-dual
model: frida
seed: 5
units: {length: m, angle: deg}
truth: {level: thesis}
experiment:
  kind: dual
  arms: [left, right]
  n: 20
  clamp: {xyz: [0.10, 0.0, 0.10], rpy: [0, -90, 0]}
  known_clamp: false
  explore: {n_seeds: 24, n_steps: 30}
noise: {joint_deg: 0.01}
validation: 10
output: {angle: deg, length: mm}
"""


def test_cli_simulate_dual(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(SMALL_DUAL)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "s.yaml"), "-o", str(out), "--quiet"]) == 0
    ds = load_dataset(out / "data.yaml")
    assert ds.kind == "dual" and ds.size == 20 and ds.name == "tiny-dual" and "T_toolA_toolB" not in ds.known
    true = read_robot(out / "truth" / "robot.yaml")
    clamp = read_truth_values(out / "truth" / "truth.yaml")["T_toolA_toolB"]
    q_true = np.loadtxt(out / "truth" / "q_true.csv", delimiter=",", skiprows=1)
    pos, rot = closure_error(true["left"], true["right"], clamp, q_true[:, :7], q_true[:, 7:])
    assert pos.max() < 1e-10 and rot.max() < 1e-10
    err = np.concatenate([ds.q["left"], ds.q["right"]], axis=1) - q_true
    assert 0 < np.abs(err).max() < 6 * np.deg2rad(0.01)  # encoder noise, written in degrees
    assert load_dataset(out / "validation" / "right.yaml").size == 10
    # same seed, same files; existing output is not overwritten
    assert main(["simulate", str(tmp_path / "s.yaml"), "-o", str(out), "--quiet"]) == 2
    assert main(["simulate", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "again"), "--quiet"]) == 0
    assert (tmp_path / "again" / "data.csv").read_text() == (out / "data.csv").read_text()


def test_cli_simulate_prints_spread(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(SMALL_DUAL)
    assert main(["simulate", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "o")]) == 0
    text = capsys.readouterr().out
    assert "joint spread, arm left" in text and "j7" in text


def test_bad_scenario_names_the_field(tmp_path):
    (tmp_path / "s.yaml").write_text(SMALL_DUAL.replace("joint_deg", "joint_sigma_furlong"))
    with pytest.raises(DataFormatError, match=r"s\.yaml: noise\.joint_sigma_furlong: unknown key"):
        load_scenario(tmp_path / "s.yaml")
    (tmp_path / "s.yaml").write_text(SMALL_DUAL.replace("kind: dual", "kind: laser"))
    with pytest.raises(DataFormatError, match="experiment.kind: expected one of"):
        load_scenario(tmp_path / "s.yaml")
    loaded = resources.files("kincal.scenarios").joinpath("klimchik3r_loaded_markers.yaml").read_text()
    (tmp_path / "s.yaml").write_text(loaded.replace("wrench_N: 2500", "wrench_N: -5"))
    with pytest.raises(DataFormatError, match=r"experiment\.wrench_N: expected a load magnitude > 0 \(N\)"):
        load_scenario(tmp_path / "s.yaml")
    (tmp_path / "s.yaml").write_text(loaded.replace("wrench_N: 2500", "wrench_N: [0, 0, -100]"))
    with pytest.raises(DataFormatError, match=r"experiment\.wrench_N"):
        load_scenario(tmp_path / "s.yaml")
    (tmp_path / "s.yaml").write_text(loaded.replace("compliance_rad_per_Nm: 1.0e-5", "compliance_rad_per_Nm: -1"))
    with pytest.raises(DataFormatError, match=r"truth\.compliance_rad_per_Nm: expected a compliance >= 0"):
        load_scenario(tmp_path / "s.yaml")


def test_simulate_accepts_builtin_scenario_names(tmp_path, capsys):
    from kincal.io.datasets import scenario_path

    assert scenario_path("frida_plate4").name == "frida_plate4.yaml"
    assert main(["simulate", "nosuch", "-o", str(tmp_path / "x")]) == 2
    assert "not a built-in scenario (frida_clamp_one, frida_dual_bracket" in capsys.readouterr().err


def test_loaded_scenario_to_elastic_calibration_through_the_cli(tmp_path):
    """The shipped paper scenario under load: kincal simulate writes loads and the true compliances, kincal
    calibrate with [kinematic, elastic] recovers the compliances within their reported uncertainty."""
    import yaml

    out = tmp_path / "sim"
    assert main(["simulate", "klimchik3r_loaded_markers", "-o", str(out), "--quiet"]) == 0
    ds = load_dataset(out / "data.yaml")
    assert ds.measured["wrench_tool"].shape == (60, 6) and np.abs(ds.measured["wrench_tool"][:, :3]).max() > 100
    true_c = read_robot(out / "truth" / "robot.yaml")["arm"].compliance
    assert 0 < true_c.min() and true_c.max() <= 1e-5
    (tmp_path / "job.yaml").write_text(yaml.safe_dump({
        "model": "klimchik3r", "data": [{"manifest": "sim/data.yaml", "noise": {"position_mm": 0.02}}],
        "free": ["kinematic", "elastic"]}))
    assert main(["calibrate", str(tmp_path / "job.yaml"), "-o", str(tmp_path / "res"), "--quiet"]) == 0
    est = {e["name"]: e for e in yaml.safe_load((tmp_path / "res" / "result.yaml").read_text())["estimates"]}
    for j, c in zip(("j1", "j2", "j3"), true_c):
        e = est[f"arm.{j}.compliance"]
        assert e["identifiable"] and abs(e["value"] - c) < 5 * e["std"] and e["std"] < 0.05 * c
