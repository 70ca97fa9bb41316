"""Deploying a calibration of a tree-structured robot (issue #14): compensation, URDF and controller export,
design, the camera simulator and the HTML report through the composite chain (a mounted arm with its carriers),
end to end on ``dual7_torso`` against the true robot."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from kincal import robots
from kincal.cli import main
from kincal.errors import DataFormatError, ModelError, ShapeError
from kincal.estimation import Noise, calibrate
from kincal.io.programs import read_program, write_program
from kincal.io.urdf import from_urdf, tree_from_urdf, tree_to_urdf
from kincal.kinematics import Robot, forward_kinematics
from kincal.kinematics.couplings import derive_readings
from kincal.kinematics.tree import tip_pose
from kincal.experiments.camera import project
from kincal.lie import se3
from kincal.lie.rotations import matrix_to_quat_wxyz
from kincal.simulate import (GENERATORS, Perturbation, generate_markers, generate_pose, perturb_robot,
                             random_configurations, workspace_sample)
from kincal.workflow.compensate import BRANCH_RAD, compensate_joints, compensate_poses
from kincal.workflow.design import design

NOISE = Noise(position=2e-5, orientation=2e-5)
TRACKER = np.array([[1.0, 0, 0, 2.0], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]])
ARMS = ("left", "right")


def calibrated_tree(seed: int, nominal: Robot | None = None):
    """(nominal, true, result): dual7_torso perturbed ("fine"), both hands' poses measured by one tracker of known
    pose (the torso moving), calibrated at level kinematic."""
    nominal = nominal or robots.load("dual7_torso")
    true = perturb_robot(nominal, "fine", rng=seed)
    data = [replace(generate_pose(true, a, n=100, rng=seed + i, noise=NOISE, known_tracker=True,
                                  T_world_tracker=TRACKER)[0], name=f"pose-{a}") for i, a in enumerate(ARMS)]
    return nominal, true, calibrate(nominal, data, "kinematic", noise=NOISE)


@pytest.fixture(scope="module")
def tree5():
    return calibrated_tree(5)


def _program(robot: Robot, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    return {a: random_configurations(robot[a], n, rng, 0.1) for a in ("torso", *ARMS)}


@pytest.mark.parametrize("seed", [5, 6])
def test_compensated_tree_program_reaches_the_intended_poses_under_the_true_robot(seed, tree5):
    nominal, true, res = tree5 if seed == 5 else calibrated_tree(seed)
    program = _program(nominal, 200, seed)
    comp = compensate_joints(nominal, res.robot, program)
    assert set(comp.held) == {"torso"} and set(comp.q) == set(ARMS)
    assert np.array_equal(comp.held["torso"], program["torso"])  # the shared torso is held, not solved
    for a in ARMS:
        ok = comp.status[a] == "ok"
        assert ok.mean() > 0.9
        intended = tip_pose(nominal, a, program)[:, :3, 3]
        before = np.linalg.norm(tip_pose(true, a, program)[:, :3, 3] - intended, axis=1)[ok]
        after = np.linalg.norm(tip_pose(true, a, {**program, a: comp.q[a]})[:, :3, 3] - intended, axis=1)[ok]
        predicted = res.predict({"torso": program["torso"][ok], a: program[a][ok]}, a,
                                register=False).position_rms_predicted
        actual = np.sqrt(np.mean(after**2))
        assert 0.5 < actual / predicted < 2.0, (a, actual, predicted)
        assert np.sqrt(np.mean(before**2)) > 100 * actual
        assert comp.change[a][ok].max() < BRANCH_RAD
        # on the calibrated model the compensated row reaches the intended pose through the calibrated torso
        T = tip_pose(res.robot, a, {**program, a: comp.q[a]})[ok]
        assert np.abs(T[:, :3, 3] - intended[ok]).max() < 1e-6


def test_cartesian_tree_targets_use_the_calibrated_torso(tree5):
    nominal, true, res = tree5
    program = _program(nominal, 30, 3)
    targets = {a: tip_pose(nominal, a, program) for a in ARMS}
    comp = compensate_poses(res.robot, targets, program, nominal=nominal)
    for a in ARMS:
        ok = comp.status[a] == "ok"
        assert ok.sum() >= 27
        T = tip_pose(res.robot, a, {"torso": program["torso"], a: comp.q[a]})
        assert np.abs(T[ok] - targets[a][ok]).max() < 1e-6
    program["torso"][4, 1] = nominal["torso"].upper[1] + 0.1  # a held torso reading past its limit
    comp = compensate_joints(nominal, res.robot, program)
    assert ("left", 4, "outside limits") in comp.failed() and ("right", 4, "outside limits") in comp.failed()


def _coupled(robot: Robot) -> Robot:
    """dual7_torso with the left arm's j7 coupled to its j5 (q7 = 0.5 q5 + 0.1): six free joints."""
    left = robot["left"].replace(couplings={"j7": {"j5": 0.5, "constant": 0.1}})
    return robot.replace_arm("left", left)


def test_a_coupled_joint_is_derived_never_solved():
    nominal = _coupled(robots.load("dual7_torso"))
    true = perturb_robot(nominal, "fine", rng=2)
    program = _program(nominal, 40, 4)
    program["left"][:, 6] = 0.5 * program["left"][:, 4] + 0.1
    comp = compensate_joints(nominal, true, program)
    q = comp.q["left"]
    assert np.allclose(q[:, 6], 0.5 * q[:, 4] + 0.1, atol=1e-12)  # the coupling holds exactly
    ok = comp.status["left"] == "ok"
    assert ok.mean() > 0.8
    T = tip_pose(true, "left", {"torso": program["torso"], "left": q})
    assert np.abs(T[ok] - tip_pose(nominal, "left", program)[ok]).max() < 1e-6


def test_missing_carrier_readings_and_unknown_arms_are_refused():
    nominal = robots.load("dual7_torso")
    program = _program(nominal, 3, 1)
    with pytest.raises(ModelError, match="mounted on 'torso'"):
        compensate_joints(nominal, nominal, {"left": program["left"]})
    with pytest.raises(ModelError, match="no arm 'head'"):
        compensate_joints(nominal, nominal, {"head": program["left"]})
    with pytest.raises(ShapeError, match="one row per target; rows: torso 2, left 3"):
        compensate_joints(nominal, nominal, {"torso": program["torso"][:2], "left": program["left"]})


def _write(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    return path


def test_cli_compensates_a_tree_program_and_bad_files_are_one_line(tmp_path, capsys, tree5):
    nominal, true, res = tree5
    from kincal.io.models import save_robot
    model = tmp_path / "calibrated.yaml"
    save_robot(res.robot, model)
    program = _program(nominal, 10, 8)
    names = [f"{a}.{j}" for a in ("torso", "left") for j in nominal[a].joint_names]
    good = _write(tmp_path / "program.csv", names, np.degrees(np.hstack([program["torso"], program["left"]])))
    out = tmp_path / "out.csv"
    code = main(["compensate", str(model), str(good), "--nominal", "dual7_torso", "-o", str(out), "--angle", "deg"])
    text = capsys.readouterr().out
    assert code in (0, 1) and "held" in text
    back, ok = _read_output(out, nominal)
    assert np.allclose(back["torso"], program["torso"], atol=1e-12)
    T = tip_pose(res.robot, "left", back)
    intended = tip_pose(nominal, "left", program)
    assert ok.sum() >= 8 and np.abs(T - intended)[ok].max() < 1e-6
    cases = (([n for n in names if not n.startswith("torso")], "column 'torso.t1': missing; arm 'left' is mounted"),
             ([*names, "head.j1"], "column 'head.j1': no arm 'head'"))
    for header, words in cases:
        bad = _write(tmp_path / "bad.csv", header, np.zeros((2, len(header))))
        assert main(["compensate", str(model), str(bad), "--nominal", "dual7_torso", "-o",
                     str(tmp_path / "o2.csv")]) == 2
        err = capsys.readouterr().err
        assert words in err and "bad.csv: line 1" in err and err.count("\n") == 1, err


def _read_output(path, robot: Robot) -> tuple[dict, np.ndarray]:
    """The compensated program's readings (rad) of torso and left, and which rows of left are ok."""
    lines = [line.split(",") for line in path.read_text().splitlines()]
    col = {c: i for i, c in enumerate(lines[0])}
    q = {a: np.radians([[float(r[col[f"{a}.{j}"]]) for j in robot[a].joint_names] for r in lines[1:]])
         for a in ("torso", "left")}
    return q, np.array([r[col["left.status"]] == "ok" for r in lines[1:]])


def test_program_columns_of_a_coupled_carrier_may_be_left_out(tmp_path):
    base = robots.load("dual7_torso")
    robot = base.replace_arm("torso", base["torso"].replace(couplings={"t2": {"t1": -0.5}}))  # the tilt follows
    header = ["torso.t1", *(f"left.j{k}" for k in range(1, 8))]
    prog = read_program(_write(tmp_path / "p.csv", header, np.full((2, 8), 0.1)), robot)
    assert np.allclose(prog.q["torso"], [[0.1, -0.05]] * 2)  # t2 derived
    with pytest.raises(DataFormatError, match="line 2, column 'torso.t2': 0.1 disagrees with the coupling"):
        read_program(_write(tmp_path / "q.csv", ["torso.t2", *header], np.full((2, 9), 0.1)), robot)
    comp = compensate_joints(robot, robot, {"torso": np.array([[0.1, 0.3]]), "left": np.full((1, 7), 0.1)})
    assert np.allclose(comp.held["torso"], [[0.1, -0.05]])  # a held carrier's coupled joint is derived too


def _random_readings(robot: Robot, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    q = {a: random_configurations(robot[a], n, rng) for a in robot.arms}
    return {a: derive_readings(robot[a].couplings, robot[a].joint_names, v) for a, v in q.items()}


@pytest.mark.parametrize("seed", [5, 6])
def test_calibrated_tree_exports_one_branched_urdf_that_reimports_to_the_same_kinematics(seed, tree5):
    pytest.importorskip("yourdfpy")
    _, _, res = tree5 if seed == 5 else calibrated_tree(seed)
    coupled = res.robot.replace_arm("torso", res.robot["torso"].replace(couplings={"t2": {"t1": -0.5, "constant": 0.1}}))
    for robot in (res.robot, coupled):
        text, notes = tree_to_urdf(robot)
        assert notes == [] and text.count('<link name="world"/>') == 1
        assert text.count('name="torso_t1"') == 1  # the shared torso once
        back = tree_from_urdf(text, "world")
        assert set(back.arms) == {"torso", "left", "right"}
        assert dict(back.mounts) == {"left": "torso", "right": "torso"}
        q = _random_readings(robot, 200, 1)
        for a in robot.arms:
            assert np.abs(tip_pose(back, a, q) - tip_pose(robot, a, q)).max() < 1e-9
    assert '<mimic joint="torso_t1" multiplier="-0.5" offset="0.1"/>' in tree_to_urdf(coupled)[0]
    assert dict(tree_from_urdf(tree_to_urdf(coupled)[0], "world")["torso"].couplings["torso_t2"]) == \
        {"torso_t1": -0.5, "constant": 0.1}


def test_a_coupling_on_several_joints_is_written_free_with_a_note():
    robot = robots.load("dual7_torso")
    robot = robot.replace_arm("left", robot["left"].replace(couplings={"j7": {"j5": 0.5, "j6": -1.0}}))
    text, notes = tree_to_urdf(robot)
    assert "<mimic" not in text and len(notes) == 1 and "j7 follows several joints (j5, j6)" in notes[0]


def test_cli_exports_the_tree_and_controller_offsets_once(tmp_path, capsys, tree5):
    pytest.importorskip("yourdfpy")
    _, _, res = tree5
    from kincal.io.models import save_robot
    model = tmp_path / "calibrated.yaml"
    save_robot(res.robot, model)
    assert main(["export", str(model), "--to", "urdf", "-o", str(tmp_path / "tree.urdf")]) == 0
    assert "left on torso" in capsys.readouterr().out
    back = tree_from_urdf(tmp_path / "tree.urdf", "world")
    q = _random_readings(res.robot, 50, 2)
    for a in ARMS:
        assert np.abs(tip_pose(back, a, q) - tip_pose(res.robot, a, q)).max() < 1e-9
    assert main(["export", str(model), "--to", "controller", "-o", str(tmp_path / "c.yaml")]) == 0
    doc = yaml.safe_load((tmp_path / "c.yaml").read_text())
    assert [e["arm"] for e in doc["arms"]] == list(res.robot.arms)  # every arm once: the torso's offsets once
    torso = next(e for e in doc["arms"] if e["arm"] == "torso")
    assert [c["offset_joint"] for c in torso["channels"]] == pytest.approx(res.robot["torso"].offsets.tolist())
    assert next(e for e in doc["arms"] if e["arm"] == "left")["mounted_on"] == "torso"
    # one mounted arm: its chain with the torso, in the world
    assert main(["export", str(model), "--arm", "left", "--to", "urdf", "-o", str(tmp_path / "left.urdf")]) == 0
    chain = from_urdf(tmp_path / "left.urdf", "world", "tool")
    qq = np.concatenate([q["torso"], q["left"]], axis=1)
    assert np.abs(forward_kinematics(chain, qq) - tip_pose(res.robot, "left", q)).max() < 1e-9
    assert main(["export", str(model), "--to", "dh", "-o", str(tmp_path / "d.yaml")]) == 2
    err = capsys.readouterr().err
    assert "exported whole as urdf or controller" in err and err.count("\n") == 1


CAMERA = np.array([[0.0, 0, -1, 2.0], [0, 1, 0, 0], [1, 0, 0, 0.6], [0, 0, 0, 1]])  # 2 m ahead, looking back


@pytest.mark.parametrize("seed", [4, 5])
def test_camera_simulated_through_the_torso_calibrates_every_offset(seed):
    nominal = robots.load("dual7_torso")
    true = perturb_robot(nominal, Perturbation(offset_rad=0.02), rng=seed)
    data = []
    for i, a in enumerate(ARMS):
        ds, truth, val = GENERATORS["camera"](true, a, n=80, rng=10 + i + seed, noise=Noise(other={"pixel": 0.1}),
                                              T_world_camera=CAMERA, known_camera=True, known_point=True)
        assert set(ds.q) == {"torso", a}  # the torso moves with the arm, its readings in the data set
        assert not np.allclose(ds.q["torso"], ds.q["torso"][0])
        clean = project(se3.transform_points(se3.inverse(CAMERA) @ tip_pose(true, a, truth.q), truth.values["p_tool_point"]),
                        ds.known["intrinsics"])[0]
        assert np.sqrt(np.mean((ds.measured["pixel"] - clean) ** 2)) < 0.2  # the pixel noise only
        data.append(replace(ds, name=f"camera-{a}"))
    res = calibrate(nominal, data, "offsets", noise=Noise(other={"pixel": 0.1}))
    assert res.status == "converged" and res.sigma2 < 1.5
    for arm in nominal.arms:
        for j, name in enumerate(nominal[arm].joint_names):
            e = res.estimate(f"{arm}.{name}.offset")
            assert abs(e.value - true[arm].offsets[j]) < 4 * e.std, (arm, name, e.value, true[arm].offsets[j], e.std)


def test_design_on_a_tree_chooses_over_the_torso_and_the_design_calibrates():
    nominal = robots.load("dual7_torso")
    d = design(nominal, "markers", {"arm": "left", "markers": 3}, 30, free="offsets", pool=300, seed=1)
    assert set(d.dataset.q) == {"torso", "left"}
    # the pan turns the arm as a tracker rotation would, the last joint turns the unknown markers
    assert set(d.unidentifiable) == {"torso.t1.offset", "left.j7.offset"}
    assert np.ptp(d.dataset.q["torso"], axis=0).min() > 0.3  # the torso's joints are designed too
    assert d.selection.value >= d.random and d.tool_rms <= d.random_tool_rms
    true = perturb_robot(nominal, Perturbation(offset_rad=0.02), rng=3)
    q = np.hstack([d.dataset.q["torso"], d.dataset.q["left"]])  # the composite's readings, carriers first
    ds, _, val = generate_markers(true, "left", configurations=q, rng=4, noise=NOISE, markers=3)
    res = calibrate(nominal, [ds], "offsets", noise=NOISE)
    assert res.status == "converged"
    for arm in ("torso", "left"):
        for j, name in enumerate(nominal[arm].joint_names):
            e = res.estimate(f"{arm}.{name}.offset")
            if f"{arm}.{name}.offset" not in d.unidentifiable:
                assert abs(e.value - true[arm].offsets[j]) < 4 * e.std, (arm, name)
    # a dual clamp sees the arms relative to each other: the torso's offsets are named, the targets hold them
    d = design(nominal, "dual", {"arms": ["left", "right"], "known_clamp": True}, 30, pool=200, seed=2)
    assert set(d.unidentifiable) == {"torso.t1.offset", "torso.t2.offset"}
    assert set(d.dataset.q) == {"torso", "left", "right"}
    assert np.all(nominal["torso"].within_limits(d.dataset.q["torso"]))


def test_html_report_of_a_tree_shows_the_tree_shared_parameters_once_and_each_tip(tree5):
    pytest.importorskip("matplotlib")
    from kincal.report.html import accuracy_map, report_html
    from kincal.report.plots import _pyplot

    plt = _pyplot()

    nominal, true, _ = tree5
    data, val = [], []
    for i, a in enumerate(ARMS):
        ds, _, v = generate_pose(true, a, n=100, rng=20 + i, noise=NOISE, known_tracker=True, T_world_tracker=TRACKER)
        data.append(replace(ds, name=f"pose-{a}"))
        val.append(v[a])
    res = calibrate(nominal, data, "kinematic", noise=NOISE, validation=val)
    sample = {a: workspace_sample(nominal, a, 60, np.random.default_rng(0)) for a in res.state.arms}
    assert set(sample["left"]) == {"torso", "left"}  # a mounted arm's sample goes through its carriers
    text = report_html(res, title="dual7_torso", workspace=sample)
    assert "Tree: which arm carries which" in text
    assert "<td>left</td><td>torso</td><td>-</td>" in text and "<td>torso</td><td>(the base)</td><td>right, left</td>" in text
    for e in res.estimates:
        if e.name.startswith("torso."):
            assert text.count(f"<td>{e.name}</td>") == 1  # a shared parameter once
    for a in ARMS:  # per-tip validation, through the torso, at the noise level
        assert f"<td>validation-{a}</td><td>{a} (on torso)</td>" in text
        fig = accuracy_map(plt, res, a, sample[a])
        assert fig._suptitle.get_text().startswith(f"arm '{a} (on torso)': predicted accuracy at 60 configurations")
        plt.close(fig)
    for v in res.validation:
        assert v.after.position_rms < 3 * NOISE.position < v.before.position_rms


def test_cli_design_from_tree_configurations_and_from_the_torso_scenario(tmp_path, capsys):
    """A configurations file of a mounted arm holds its carriers' columns; the design's targets set the torso
    once; the torso_dual_clamp scenario names the torso offsets the clamp cannot see."""
    nominal = robots.load("dual7_torso")
    rng = np.random.default_rng(5)
    pool = np.hstack([random_configurations(nominal[a], 150, rng, 0.1) for a in ("torso", "left")])
    header = ",".join(f"{a}.{j}" for a in ("torso", "left") for j in nominal[a].joint_names)
    np.savetxt(tmp_path / "cell.csv", pool, delimiter=",", header=header, comments="")
    (tmp_path / "job.yaml").write_text("model: dual7_torso\nfree: offsets\ndata:\n  - configurations: cell.csv\n"
                                       "    experiment: {kind: markers, arm: left, markers: 3}\n"
                                       "    noise: {position_mm: 0.02}\n")
    assert main(["design", str(tmp_path / "job.yaml"), "-n", "25", "-o", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert "tree: right on torso, left on torso" in out
    chosen = np.loadtxt(tmp_path / "a" / "targets.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "a" / "targets.csv").read_text().splitlines()[0] == header
    assert all(any(np.allclose(row, p) for p in pool) for row in chosen)  # each a row of the file, torso included
    assert main(["design", "torso_dual_clamp", "-n", "30", "--pool", "200", "-o", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "not identifiable from this experiment: torso.t1.offset, torso.t2.offset" in out
    doc = yaml.safe_load((tmp_path / "b" / "design.yaml").read_text())
    assert doc["not_identifiable"] == ["torso.t1.offset", "torso.t2.offset"]
    assert doc["mounts"] == {"right": "torso", "left": "torso"}
    head = (tmp_path / "b" / "targets.csv").read_text().splitlines()[0].split(",")
    assert head[:2] == ["torso.t1", "torso.t2"] and len(head) == 16


def test_cartesian_tree_program_through_the_files(tmp_path, tree5):
    nominal, _, res = tree5
    program = _program(nominal, 6, 9)
    T = tip_pose(nominal, "right", program)
    quat = np.array([matrix_to_quat_wxyz(R) for R in T[:, :3, :3]])
    header = [*(f"torso.{j}" for j in nominal["torso"].joint_names), *(f"right.{j}" for j in nominal["right"].joint_names),
              *(f"right.{k}" for k in ("x", "y", "z", "qw", "qx", "qy", "qz"))]
    path = _write(tmp_path / "poses.csv", header, np.hstack([program["torso"], program["right"], T[:, :3, 3], quat]))
    prog = read_program(path, nominal)
    assert prog.form == "poses" and set(prog.poses) == {"right"} and set(prog.q) == {"torso", "right"}
    comp = compensate_poses(res.robot, prog.poses, prog.q, nominal=nominal)
    assert set(comp.held) == {"torso"}
    write_program(tmp_path / "out.csv", prog, res.robot, comp)
    head = (tmp_path / "out.csv").read_text().splitlines()[0].split(",")
    assert head[:2] == ["torso.t1", "torso.t2"] and head[-1] == "right.status"
    ok = comp.status["right"] == "ok"
    reached = tip_pose(res.robot, "right", {"torso": program["torso"], "right": comp.q["right"]})
    assert ok.sum() >= 5 and np.abs(reached[ok] - T[ok]).max() < 1e-6


def test_cli_fk_of_a_mounted_arm_is_its_world_pose(capsys):
    nominal = robots.load("dual7_torso")
    q = {"torso": np.array([0.2, 0.1]), "left": np.linspace(-0.3, 0.3, 7)}
    args = ["fk", "dual7_torso", "--arm", "left", "--q-rad", ",".join(str(float(x)) for x in np.concatenate([q["torso"], q["left"]])),
            "--json"]
    assert main(args) == 0
    data = yaml.safe_load(capsys.readouterr().out)
    assert np.allclose(data["matrix"], tip_pose(nominal, "left", q), atol=1e-12)
