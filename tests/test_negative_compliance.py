"""A compliance estimated below 0 is kept in the calibrated model as the solver fitted it, and reported: beyond
3 std of 0 the result is not trusted (exit code 5), within them a warning (issue 14: zeroed silently, the
returned model was 21 mm off where the solver's fit was 3.9 mm, under a "converged")."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from kincal.cli import main
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import Stage, calibrate, evaluate
from kincal.estimation.plausibility import (
    NEGATIVE_SIGMAS,
    ROUND_OFF_COMPLIANCE,
    NegativeCompliance,
    negative_compliance_notes,
)
from kincal.io.datasets import write_dataset
from kincal.io.models import dump_robot, load_robot, parse_robot, save_robot
from kincal.kinematics import Robot
from kincal.noise import Noise as Stated
from kincal.params import State
from kincal.robots import load
from kincal.simulate.generators import generate_markers, generate_pose
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot

SIGMA = 2e-5  # tracker noise, m
STATED = Stated(position=SIGMA, orientation=1e-5, joint=0.0)
LOAD_N = 2500.0


def _truth(compliance=(1e-5, 0.0, 2e-5), nodes=None):
    """klimchik3r, perturbed, with joint 2 rigid (or with ``nodes``: its compliance by angle)."""
    true = perturb_robot(load("klimchik3r"), "fine", 3)
    arm = true["arm"].replace(compliance=list(compliance), compliance_nodes=nodes)
    return Robot(true.name, {"arm": arm})


def _data(true, seed, flip=False):
    """Loaded markers; ``flip``: the loads written with the wrong sign (a user's sign error)."""
    ds, _, _ = generate_markers(true, n=30, rng=seed, markers=3, noise=Noise(position=SIGMA), wrench=LOAD_N)
    if flip:
        ds = replace(ds, measured={**ds.measured, "wrench_tool": -ds.measured["wrench_tool"]})
    return ds


def _nominal(nodes=None):
    r = load("klimchik3r")
    return r if nodes is None else Robot(r.name, {"arm": r["arm"].replace(compliance_nodes=nodes)})


def assert_model_is_the_fit(res, noise=STATED):
    """The returned Robot predicts exactly what the solver fitted: its residuals (with the solve's frames) are
    the solver's final residuals, and re-fitting only the frames to it gives the solver's RMS."""
    problem = res.problem
    at_model = State.from_robot(res.robot, res.state.extras, res.state.kinds)
    for fitted, model in zip(problem.residuals(res.state), problem.residuals(at_model)):
        np.testing.assert_allclose(model.r, fitted.r, rtol=0, atol=1e-12)
    again = evaluate(res.robot, [e.dataset for e in problem.experiments], noise=noise)
    for a, b in zip(again, res.after):
        assert a.position_rms == pytest.approx(b.position_rms, rel=1e-6, abs=1e-12)


def test_wrong_load_sign_gives_negative_compliances_kept_in_the_model_and_not_trusted():
    res = calibrate(_nominal(), [_data(_truth(), 1, flip=True)], ["kinematic", "elastic"], noise=STATED)
    assert res.status == "converged"
    assert not res.physical and not res.trusted and not res.success
    names = [c.name for c in res.negative_compliances]
    assert names == ["arm.j1.compliance", "arm.j3.compliance"]
    for c in res.negative_compliances:
        e = res.estimate(c.name)
        assert (c.value, c.std) == (e.value, e.std) and c.value < -NEGATIVE_SIGMAS * c.std and c.significant
    np.testing.assert_allclose(res.robot["arm"].compliance, [res.estimate(f"arm.j{i}.compliance").value
                                                             for i in (1, 2, 3)], rtol=0, atol=0)
    assert res.robot["arm"].compliance[0] == pytest.approx(-1e-5, rel=1e-3)  # the truth with the sign flipped
    assert res.robot["arm"].allow_negative_compliance
    assert_model_is_the_fit(res)
    note = next(m for m in res.messages if "below 0" in m)
    assert note.startswith("not trusted: compliance estimated below 0 by more than 3 std: arm.j1.compliance = ")
    assert "arm.j3.compliance" in note and "std" in note and "exit code 5" in note and "\n" not in note


def test_a_stiff_joint_scattering_below_zero_is_a_warning_and_kept():
    """Joint 2 rigid in truth: with tracker noise its estimate falls below 0 on some seeds (seed 1: -0.8 std)."""
    res = calibrate(_nominal(), [_data(_truth(), 1)], ["kinematic", "elastic"], noise=STATED)
    assert res.status == "converged" and res.physical and res.trusted
    (c,) = res.negative_compliances
    assert c.name == "arm.j2.compliance" and -NEGATIVE_SIGMAS * c.std < c.value < 0 and not c.significant
    assert res.robot["arm"].compliance[1] == c.value  # not held at 0
    assert_model_is_the_fit(res)
    note = next(m for m in res.messages if "below 0" in m)
    assert note.startswith("warning: compliance estimated below 0 within 3 std of 0")
    assert f"arm.j2.compliance = {c.value:.3g} rad/Nm (std {c.std:.2g})" in note


def test_a_rigid_joint_in_noise_free_data_is_zero_up_to_round_off_not_reported():
    ds, _, _ = generate_markers(_truth(), n=30, rng=4, markers=3, wrench=LOAD_N)
    res = calibrate(_nominal(), [ds], ["kinematic", "elastic"])
    assert -ROUND_OFF_COMPLIANCE < res.estimate("arm.j2.compliance").value < 0  # -7e-20 rad/Nm
    assert res.negative_compliances == () and res.physical and res.trusted
    assert not any("below 0" in m for m in res.messages)


NODES = {"j2": [[-1.0, 1e-5], [1.0, 2e-5]]}


def test_angle_dependent_compliance_below_zero_is_kept_per_node():
    res = calibrate(_nominal(NODES), [_data(_truth(nodes=NODES), 2, flip=True)], ["kinematic", "elastic"],
                    noise=STATED)
    table = res.robot["arm"].compliance_nodes["j2"]
    nodes = [res.estimate(n).value for n in ("arm.j2.compliance@-57deg", "arm.j2.compliance@57deg")]
    np.testing.assert_array_equal(table[:, 1], nodes)
    assert np.all(table[:, 1] < 0)
    assert {"arm.j2.compliance@-57deg", "arm.j2.compliance@57deg"} <= {c.name for c in res.negative_compliances}
    assert not res.trusted
    assert_model_is_the_fit(res)
    back = parse_robot(dump_robot(res.robot), "calibrated.yaml")
    assert back == res.robot and back["arm"].allow_negative_compliance


def test_calibrated_model_with_negative_compliance_round_trips_and_hand_written_ones_are_refused(tmp_path):
    res = calibrate(_nominal(), [_data(_truth(), 1, flip=True)], ["kinematic", "elastic"], noise=STATED)
    path = save_robot(res.robot, tmp_path / "model.yaml")
    text = path.read_text()
    assert "allow_negative_compliance: true" in text
    back = load_robot(path)
    assert back == res.robot and back["arm"].allow_negative_compliance
    np.testing.assert_array_equal(back["arm"].compliance, res.robot["arm"].compliance)
    (tmp_path / "hand.yaml").write_text(text.replace("allow_negative_compliance: true", ""))
    with pytest.raises(DataFormatError, match=r"hand.yaml: arms.arm.joints\[0\].compliance: expected a compliance "
                                              r">= 0 .*allow_negative_compliance: true") as info:
        load_robot(tmp_path / "hand.yaml")
    assert "\n" not in str(info.value)
    data = yaml.safe_load(text)
    data["arms"]["arm"]["allow_negative_compliance"] = "yes"
    with pytest.raises(DataFormatError, match=r"arms.arm.allow_negative_compliance: expected true or false"):
        parse_robot(yaml.safe_dump(data), "m.yaml")


def test_arm_model_refuses_negative_compliance_unless_allowed():
    arm = load("klimchik3r")["arm"]
    with pytest.raises(ModelError, match="compliance must be >= 0.*allow_negative_compliance"):
        arm.replace(compliance=[-1e-6, 0, 0])
    with pytest.raises(ModelError, match="compliances must be >= 0"):
        arm.replace(compliance_nodes={"j2": [[-1.0, -1e-6], [1.0, 0.0]]})
    ok = arm.replace(compliance=[-1e-6, 0, 0], allow_negative_compliance=True)
    assert ok.compliance[0] == -1e-6


def test_cli_says_not_trusted_and_exits_5_and_the_model_loads_back(tmp_path, capsys):
    r = load("klimchik3r")
    write_dataset(_data(_truth(), 1, flip=True), tmp_path / "loaded.yaml", r, model="klimchik3r")
    (tmp_path / "job.yaml").write_text(
        "format: kincal-job\nversion: 1\nmodel: klimchik3r\nfree: [kinematic, elastic]\ndata:\n"
        f"  - {{manifest: loaded.yaml, noise: {{position_mm: {SIGMA * 1e3}}}}}\n")
    assert main(["calibrate", str(tmp_path / "job.yaml"), "-o", str(tmp_path / "out")]) == 5
    out = capsys.readouterr().out
    assert "converged (NOT TRUSTED: compliance below 0 beyond the noise: arm.j1.compliance, arm.j3.compliance)" \
        in out.replace("\n", " ")
    assert "not trusted: compliance estimated below 0 by more than 3 std" in out
    result = yaml.safe_load((tmp_path / "out" / "result.yaml").read_text())
    assert result["trusted"] is False and result["status"] == "converged"
    model = load_robot(tmp_path / "out" / "model.yaml")
    values = {e["name"]: e["value"] for e in result["estimates"]}
    np.testing.assert_allclose(model["arm"].compliance, [values[f"arm.j{i}.compliance"] for i in (1, 2, 3)],
                               rtol=1e-12)
    assert model["arm"].compliance[0] < 0


# ------------------------------------------------------------------ the returned model is the solver's fit


def _loaded_markers():
    return _nominal(), [_data(_truth(), 3)], STATED


def _loaded_markers_with_nodes():
    return _nominal(NODES), [_data(_truth(nodes=NODES), 4)], STATED


def _pose_and_markers_of_frida():
    """Two arms, a tool frame and a tracker: Frida's right arm seen as poses, the left as markers (no loads)."""
    frida = load("frida")
    true = perturb_robot(frida, "thesis", 2)
    pose, _, _ = generate_pose(true, "right", n=25, rng=1, noise=Noise(position=2e-5, orientation=1e-4))
    markers, _, _ = generate_markers(true, "left", n=25, rng=2, markers=3, noise=Noise(position=2e-5))
    return frida, [pose, markers], Stated(position=2e-5, orientation=1e-4, joint=0.0)


CASES = {"loaded markers": _loaded_markers, "compliance nodes": _loaded_markers_with_nodes,
         "frida pose and markers": _pose_and_markers_of_frida}
LEVELS = {"loaded markers": ["offsets", "kinematic", "elastic", ["kinematic", "elastic"]],
          "compliance nodes": [["kinematic", "elastic"]],
          "frida pose and markers": ["offsets", "kinematic"]}


@pytest.mark.parametrize("case, free", [(c, f) for c in CASES for f in LEVELS[c]])
def test_the_returned_robot_predicts_the_solvers_final_residuals(case, free):
    """Guard (issue 14): whatever the level, ``Result.robot`` is the state the solver ended at, so a
    "converged" never describes a fit the returned model does not have."""
    robot, data, noise = CASES[case]()
    res = calibrate(robot, data, free, noise=noise)
    assert res.status in ("converged", "misfit")  # at offsets, loads unmodelled: a misfit, as it should
    assert_model_is_the_fit(res, noise)


def test_a_staged_solve_returns_its_last_stages_fit():

    robot, data, noise = _loaded_markers()
    res = calibrate(robot, data, noise=noise, stages=[Stage("offsets", name="offsets"),
                                                      Stage(["kinematic", "elastic"], name="all")])
    assert len(res.stages) == 2
    assert_model_is_the_fit(res)


def test_an_undetermined_negative_compliance_is_significant_and_said_to_be_undetermined():
    """A compliance below 0 that the data cannot determine (std nan) is not noise around 0: it makes the result
    untrusted, and its line says it is undetermined rather than printing 'std nan'."""
    found = (NegativeCompliance("torso.t1.lateral_x", -8.5e-5, float("nan"), "rad/Nm"),
             NegativeCompliance("arm.j2.compliance", -1e-4, 1e-3, "rad/Nm"))
    assert found[0].significant and not found[1].significant
    far, near = negative_compliance_notes(found)
    assert far.startswith("not trusted: compliance estimated below 0 by more than 3 std: torso.t1.lateral_x = ")
    assert "(undetermined by the data: no std)" in far and "nan" not in far
    assert "arm.j2.compliance = -0.0001 rad/Nm (std 0.001)" in near
