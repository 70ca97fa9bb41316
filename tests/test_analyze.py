"""``analyze`` / ``kincal analyze`` (issue #11, items 1-3): rank and named null space before measuring,
observability indices, predicted standard deviations that match the scatter of real calibrations, the thesis'
Table 4.10 and Table 4.14, and the first-order effect of errors in held parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kincal import robots
from kincal.analysis.observability import observability
from kincal.baselines.rank import thesis_rank
from kincal.cli import main
from kincal.data import Dataset
from kincal.errors import KincalError, ModelError
from kincal.estimation import Noise, calibrate
from kincal.io.jobs import load_job
from kincal.workflow.plan import load_plan_job
from kincal.lie import se3
from kincal.simulate import generate_clamp, generate_dual, generate_markers
from kincal.workflow.analyze import analyze

FRIDA = robots.load("frida")
# The thesis' clamp error of Table 4.14: 1 cm along x and y, -1 cm along z, -0.1 rad about x, +0.1 about y and z.
THESIS_CLAMP_ERROR = {"clamp.v_x": 0.01, "clamp.v_y": 0.01, "clamp.v_z": -0.01,
                      "clamp.w_x": -0.1, "clamp.w_y": 0.1, "clamp.w_z": 0.1}


def _true_offsets(seed: int, size: float = 0.05):
    rng = np.random.default_rng(seed)
    true = FRIDA
    for arm in ("left", "right"):
        true = true.replace_arm(arm, true[arm].replace(offsets=rng.uniform(-size, size, 7)))
    return true


def _with_clamp(ds: Dataset, T) -> Dataset:
    return Dataset(ds.kind, ds.robot, ds.arms, ds.q, ds.measured, {"T_toolA_toolB": T}, ds.name, ds.meta)


def test_observability_indices_by_hand():
    s = np.array([4.0, 2.0, 0.5])
    o = observability(s, 9)
    assert o.O1 == pytest.approx((4 * 2 * 0.5) ** (1 / 3) / 3)
    assert (o.O2, o.O3, o.O4) == pytest.approx((0.125, 0.5, 0.0625))
    assert o.O5 == pytest.approx(1 / (0.25 + 0.5 + 2))
    with pytest.raises(KincalError):
        observability(np.array([1.0, 0.0]), 3)


def test_more_configurations_raise_the_indices_but_not_o1_per_configuration():
    """O3 (the worst direction) grows like sqrt(N); O1 is normalized per configuration."""
    ds, _, _ = generate_dual(FRIDA, n=40, rng=0, noise=Noise(joint=1e-5), known_clamp=True)
    small = analyze(FRIDA, [ds.subset(np.arange(20))], "offsets", workspace=10).plan.observability
    large = analyze(FRIDA, [ds], "offsets", workspace=10).plan.observability
    assert large.O3 > 1.2 * small.O3
    assert large.O1 == pytest.approx(small.O1, rel=0.3)


def test_single_clamp_unknown_fixture_names_j1_and_j7_before_measuring():
    ds, _, _ = generate_clamp(FRIDA, "right", n=40, rng=2, noise=Noise(joint=1e-5))
    an = analyze(FRIDA, [ds], "offsets", workspace=20)
    p = an.plan
    assert p.rank == 11
    assert {d.pivot for d in p.identifiability.directions} == {"right.j1.offset", "right.j7.offset"}
    assert not p.estimate("right.j1.offset").identifiable and np.isnan(p.estimate("right.j7.offset").std)
    assert np.isfinite(p.estimate("right.j4.offset").std)
    assert not an.predictions["right"].trusted  # j7 moves the tool: said before anyone measures


@pytest.mark.parametrize("kind", ["dual", "markers"])
def test_predicted_std_matches_the_scatter_of_calibrations(kind):
    """The plan's standard deviations (variance factor 1) against the spread of estimates over 16 noise seeds
    on the same configurations: within a factor 1.5 (geometric mean over the identifiable offsets)."""
    true = _true_offsets(3, 0.01)
    if kind == "dual":
        clean, _, _ = generate_dual(true, n=40, rng=5, known_clamp=True)
        noise = Noise(joint=2e-5)

        def fresh(rng):
            q = {a: clean.q[a] + rng.normal(0, 2e-5, clean.q[a].shape) for a in clean.arms}
            return Dataset(clean.kind, clean.robot, clean.arms, q, clean.measured, clean.known, clean.name)
    else:
        clean, _, _ = generate_markers(true, "right", n=40, rng=5)
        noise = Noise(position=5e-5)

        def fresh(rng):
            m = {k: v + rng.normal(0, 5e-5, v.shape) for k, v in clean.measured.items()}
            return Dataset(clean.kind, clean.robot, clean.arms, clean.q, m, clean.known, clean.name)
    plan = analyze(FRIDA, [fresh(np.random.default_rng(99))], "offsets", noise=noise, workspace=10).plan
    ests = np.array([[e.value for e in calibrate(FRIDA, [fresh(np.random.default_rng(s))], "offsets", noise=noise,
                                                 outliers="keep").estimates] for s in range(16)])
    ok = np.array([e.identifiable and e.unit == "rad" for e in plan.estimates])
    assert ok.sum() >= 5
    ratio = ests.std(axis=0, ddof=1)[ok] / np.array([e.std for e in plan.estimates])[ok]
    assert 0.67 < np.exp(np.mean(np.log(ratio))) < 1.5, ratio


def test_thesis_table_4_10_rank_and_null_vector():
    """Thesis Table 4.10: one arm measured by the other, full pose. Twists + T_st: rank 48 of 48; twists +
    offsets: 48 of 49, the null vector dq1, dq3, dv2,2, dw2,1 (joints 1 and 3 share an axis at zero)."""
    rng = np.random.default_rng(0)
    for arm in ("right", "left"):
        m = FRIDA[arm]
        q = rng.uniform(np.maximum(m.lower, -3), np.minimum(m.upper, 3), (10, 7))
        full = thesis_rank(m, q, ("twists", "home"))
        assert (full.shape, full.rank, full.full) == ((60, 48), 48, 48) and not full.null_vectors
        off = thesis_rank(m, q, ("twists", "offsets"))
        assert (off.shape, off.rank, off.full) == ((60, 49), 48, 49)
        (vec,) = off.null_vectors
        named = dict(vec)
        assert set(named) == {"dq1", "dq3", "dv2,2", "dw2,1"}
        lead = named["dq1"]
        assert named["dq3"] / lead == pytest.approx(-1) and named["dw2,1"] / lead == pytest.approx(1)
        assert named["dv2,2"] / lead == pytest.approx(0.11)  # the height of joint 2's axis


def test_thesis_table_4_14_clamp_error_spoils_dual_offsets_first_order_matches_nonlinear():
    """Table 4.14: a clamp off by 1 cm / 0.1 rad moves the dual-arm offsets by about 0.1 rad (thesis: norm
    0.116 per arm). The first-order prediction matches a nonlinear calibration with the wrong clamp."""
    true = _true_offsets(0)
    ds, _, _ = generate_dual(true, n=60, rng=1, noise=Noise(joint=1e-5), known_clamp=True)
    an = analyze(FRIDA, [ds], "offsets", errors=THESIS_CLAMP_ERROR, workspace=50)
    names = [e.name for e in an.plan.estimates]
    right, left = (np.array([n.startswith(a) for n in names]) for a in ("right.", "left."))
    base = calibrate(FRIDA, [ds], "offsets")
    e = np.array([THESIS_CLAMP_ERROR[k] for k in ("clamp.v_x", "clamp.v_y", "clamp.v_z", "clamp.w_x",
                                                   "clamp.w_y", "clamp.w_z")])
    for scale, tol in ((0.1, 0.03), (1.0, 0.1)):
        wrong = calibrate(FRIDA, [_with_clamp(ds, se3.exp(scale * e) @ ds.known["T_toolA_toolB"])], "offsets")
        moved = np.array([wrong.estimate(n).value - base.estimate(n).value for n in names])
        for side in (right, left):
            assert np.linalg.norm(moved[side]) == pytest.approx(scale * np.linalg.norm(an.shift[side]), rel=tol)
        assert wrong.status == "misfit"  # a wrong clamp is not explained: never reads as success
    assert 0.05 < np.linalg.norm(an.shift[right]) < 0.2 and 0.05 < np.linalg.norm(an.shift[left]) < 0.2
    noise_floor = max(e.std for e in an.plan.estimates)
    assert np.linalg.norm(an.shift) > 1000 * noise_floor
    assert min(t.position_rms for t in an.error_tool.values()) > 1e-3  # millimetres at the tool


def test_estimating_the_clamp_removes_the_effect():
    """With the clamp estimated (not held) there is nothing to propagate, and the identifiable offsets come out
    at the noise floor whatever the clamp's true value."""
    true = _true_offsets(0)
    ds, _, _ = generate_dual(true, n=60, rng=1, noise=Noise(joint=1e-5), known_clamp=False)
    an = analyze(FRIDA, [ds], "offsets", workspace=20)
    assert an.plan.sensitivity is None and not an.held_tool
    with pytest.raises(ModelError, match="nothing is held"):
        analyze(FRIDA, [ds], "offsets", errors={"clamp.v_x": 0.01}, workspace=20)
    res = calibrate(FRIDA, [ds], "offsets", noise=Noise(joint=1e-5))
    for arm in ("right", "left"):
        for j in range(7):
            est = res.estimate(f"{arm}.j{j + 1}.offset")
            if est.identifiable:
                assert abs(est.value - true[arm].offsets[j]) < 6 * est.std + 1e-9


def test_held_parameter_patterns_and_errors_checked():
    ds, _, _ = generate_dual(FRIDA, n=30, rng=0, noise=Noise(joint=1e-5), known_clamp=True)
    an = analyze(FRIDA, [ds], "offsets", held=["clamp.w_*"], workspace=10)
    assert an.plan.sensitivity.held == ("clamp.w_x", "clamp.w_y", "clamp.w_z")
    with pytest.raises(ModelError, match="matches no fixed parameter"):
        analyze(FRIDA, [ds], "offsets", held=["right.j1.offset"], workspace=10)
    with pytest.raises(KincalError, match="not a held parameter"):
        analyze(FRIDA, [ds], "offsets", held=["clamp.w_*"], errors={"clamp.v_x": 0.01}, workspace=10)
    with pytest.raises(ModelError, match="workspace"):
        analyze(FRIDA, [ds], "offsets", workspace=1)


def test_cli_analyze_scenario_and_json(tmp_path, capsys):
    assert main(["analyze", "frida_clamp_one", "--workspace", "20"]) == 0
    out = capsys.readouterr().out
    assert "rank 11 of 13" in out and "right.j7.offset cannot be identified" in out and "O1" in out
    assert main(["analyze", "src/kincal/scenarios/frida_dual_bracket.yaml", "--workspace", "20", "--json",
                 "--error", "clamp.v_x=10mm", "--error", "clamp.w_y=0.1rad"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["rank"] == data["free"] and set(data["observability"]) == {"O1", "O2", "O3", "O4", "O5"}
    assert data["errors"]["given"] == {"clamp.v_x": 0.01, "clamp.w_y": 0.1}
    assert all(v["position_rms"] > 0 for v in data["errors"]["tool"].values())


def test_cli_analyze_job_with_data(tmp_path, capsys):
    """A job's data sets (here simulated and written by ``kincal simulate``) analysed at the nominal model."""
    assert main(["simulate", "frida_dual_bracket", "-o", str(tmp_path / "sim"), "--quiet"]) == 0
    job = tmp_path / "job.yaml"
    job.write_text("format: kincal-job\nversion: 1\nmodel: frida\ndata: [sim/data.yaml]\nfree: offsets\n")
    capsys.readouterr()
    assert main(["analyze", str(job), "--workspace", "20", "--held", "clamp.v_*"]) == 0
    out = capsys.readouterr().out
    assert "rank 14 of 14" in out and "clamp.v_x" in out and "clamp.w_x" not in out


def test_cli_analyze_bad_error_spelling(capsys):
    assert main(["analyze", "src/kincal/scenarios/frida_dual_bracket.yaml", "--error", "clamp.v_x=10"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unit mm, m, deg or rad" in err


# ------------------------------------------- jobs without measured data (kincal.io.planjobs, kincal.workflow.plan)

def _plan_job(tmp_path, entry: str, model: str = "ur10", free: str = "kinematic", name: str = "plan.yaml"):
    job = tmp_path / name
    job.write_text(f"format: kincal-job\nmodel: {model}\nfree: {free}\ndata:\n  - {entry}\n")
    return job


def test_job_naming_a_scenario_analyses_like_the_scenario(tmp_path, capsys):
    """`data: [{scenario: frida_clamp_one}]`: no data file anywhere; the CLI and Python give the scenario's
    analysis (rank 11 of 13, j1 and j7 named)."""
    job = _plan_job(tmp_path, "scenario: frida_clamp_one", "frida", "offsets")
    assert main(["analyze", str(job), "--workspace", "20", "--json"]) == 0
    from_job = json.loads(capsys.readouterr().out)
    assert main(["analyze", "frida_clamp_one", "--workspace", "20", "--json"]) == 0
    from_scenario = json.loads(capsys.readouterr().out)
    assert (from_job["rank"], from_job["free"]) == (11, 13)
    for key in ("rank", "free", "configurations", "unidentifiable", "observability"):
        assert from_job[key] == from_scenario[key], key
    job = load_plan_job(job)
    assert [d.name for d in job.datasets] == ["frida-clamp-one"] and job.datasets[0].size == 200
    an = analyze(job.robot, job.datasets, job.free, noise=job.noise, workspace=20)
    assert an.plan.rank == 11 and {"right.j1.offset", "right.j7.offset"} == {
        e.name for e in an.plan.estimates if e.name.endswith(".offset") and not e.identifiable}


def test_job_naming_configurations_predicts_with_the_stated_noise(tmp_path, capsys):
    """A configurations file (kincal design's targets.csv) and the experiment that will measure it: the
    predicted standard deviations scale with the stated noise (whitened Jacobian), from the CLI and Python."""
    assert main(["design", "ur10_tracker_markers", "-n", "30", "--pool", "300", "-o", str(tmp_path / "d")]) == 0
    capsys.readouterr()
    exp = "experiment: {kind: markers, arm: arm, markers: 3}"
    stds = {}
    for sigma in (0.05, 0.1):
        job = _plan_job(tmp_path, f"configurations: d/targets.csv\n    {exp}\n    noise: {{position_mm: {sigma}}}",
                        name=f"plan{sigma}.yaml")
        assert main(["analyze", str(job), "--workspace", "20", "--json"]) == 0
        data = json.loads(capsys.readouterr().out)
        assert (data["rank"], data["configurations"]) == (33, 30)
        stds[sigma] = np.array([e["std"] for e in data["estimates"] if e["identifiable"]])
        job = load_plan_job(job)
        assert job.datasets[0].name == "targets" and job.datasets[0].size == 30
        assert job.noise["targets"].position == pytest.approx(sigma * 1e-3)
    np.testing.assert_allclose(stds[0.1], 2 * stds[0.05], rtol=1e-6)
    # the same file in degrees, with the frames the experiment needs given as known
    q = np.loadtxt(tmp_path / "d" / "targets.csv", delimiter=",", skiprows=1)
    header = (tmp_path / "d" / "targets.csv").read_text().splitlines()[0]
    np.savetxt(tmp_path / "deg.csv", np.degrees(q), delimiter=",", header=header, comments="")
    job = _plan_job(tmp_path, "configurations: deg.csv\n    units: {angle: deg, length: mm}\n    experiment: "
                    "{kind: pose, arm: arm, known_tracker: true, T_world_tracker: {xyz: [2000, 0, 500]}}", name="deg.yaml")
    ds = load_plan_job(job).datasets[0]
    np.testing.assert_allclose(ds.q["arm"], q, atol=1e-12)
    np.testing.assert_allclose(ds.known["T_world_tracker"][:3, 3], [2.0, 0.0, 0.5])
    assert analyze(load_plan_job(job).robot, [ds], "offsets", workspace=10).plan.rank == 6


@pytest.mark.parametrize("entry, words", [
    ("configurations: nope.csv\n    experiment: {kind: markers, arm: arm}", "nope.csv: no such file"),
    ("configurations: c.csv\n    experiment: {kind: laser, arm: arm}", "experiment.kind: expected one of"),
    ("configurations: c.csv", "experiment: required with configurations"),
    ("configurations: extra.csv\n    experiment: {kind: pose, arm: arm}", "column 'speed': not a joint"),
    ("configurations: typo.csv\n    experiment: {kind: pose, arm: arm}", "column 'arm.elbow': missing"),
    ("configurations: c.csv\n    experiment: {kind: camera, arm: arm}", "name a scenario instead"),
    ("configurations: c.csv\n    experiment: {kind: pose, arm: arm}\n    colour: red", "unknown key(s) ['colour']"),
    ("scenario: no_such_scenario", "not a built-in scenario"),
    ("scenario: frida_clamp_one", "the job's model is 'ur10'"),
    ("scenario: missing/s.yaml", "no such file"),
])
def test_plan_job_bad_input_one_line(tmp_path, capsys, entry, words):
    cols = "arm.shoulder_pan,arm.shoulder_lift,arm.elbow,arm.wrist_1,arm.wrist_2,arm.wrist_3"
    (tmp_path / "c.csv").write_text(f"{cols}\n0,-1,1,0,1,0\n")
    (tmp_path / "extra.csv").write_text(f"{cols},speed\n0,-1,1,0,1,0,3\n")
    (tmp_path / "typo.csv").write_text(f"{cols.replace('elbow', 'elbw')}\n0,-1,1,0,1,0\n")
    job = _plan_job(tmp_path, entry)
    for command in (["analyze", str(job)], ["design", str(job), "-n", "5", "-o", str(tmp_path / "o")]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err


def test_io_only_reads_a_plan_job_and_the_workflow_simulates_it(tmp_path):
    """io parses a plan entry to plain data (kincal.io.planjobs imports no simulation); io's load_job refuses a
    plan job in one line, the workflow's load_plan_job makes its data sets, marked as planned."""
    import inspect
    import kincal.io.planjobs as planjobs
    assert "kincal.simulate" not in inspect.getsource(planjobs)
    job = _plan_job(tmp_path, "scenario: frida_clamp_one", "frida", "offsets")
    with pytest.raises(KincalError, match=r"data\[0\]: the data set is a plan \(scenario: frida_clamp_one\), not "
                                          "measured data") as e:
        load_job(job)
    assert "\n" not in str(e.value)
    assert load_plan_job(job).datasets[0].meta["planned"] == "scenario: frida_clamp_one"


def test_calibrate_refuses_a_plan_job(tmp_path, capsys):
    """A plan holds the nominal robot's own readings: calibrating it would 'converge' on nothing measured."""
    job = _plan_job(tmp_path, "scenario: frida_clamp_one", "frida", "offsets")
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "is a plan (scenario: frida_clamp_one), not measured data" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()
