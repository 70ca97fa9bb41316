"""Staged solves (issue #13, item 2): ``calibrate(stages=...)`` and a job's ``stages:``; docs/calibration.md
"Staged solves"."""

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from kincal.cli import main
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import Stage, calibrate
from kincal.io.datasets import load_scenario, write_simulation
from kincal.io.jobs import load_job
from kincal.simulate.scenario import build_scenario, run
from kincal.workflow import run_job

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples" / "staged"
LOADED = build_scenario(load_scenario("klimchik3r_loaded_markers"))
GEOMETRY = ["kinematic", "elastic"]
# the paper's two steps: tracker and markers with the arm nominal, then geometry and compliance with them held
PAPER = [Stage(["tracker", "markers"], name="base-and-tool"),
         Stage(GEOMETRY, fixed=["tracker", "markers"], name="geometry-and-compliance")]
# the same first stage, then the simultaneous solve's free set
SAME_FINAL = [Stage(["tracker", "markers"], name="base-and-tool"), Stage(GEOMETRY, name="all")]
COMPLIANCES = [f"arm.j{i}.compliance" for i in (1, 2, 3)]


def _simulate(scenario, seed, n_validation=20):
    return run(replace(scenario, seed=seed, n_validation=n_validation))


def _chi2(result):
    return sum(s.chi2 for s in result.after)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_staged_recovers_the_truth_like_the_simultaneous_solve(seed):
    true, ds, _, _ = _simulate(LOADED, seed)
    simultaneous = calibrate(LOADED.robot, [ds], GEOMETRY)
    staged = calibrate(LOADED.robot, [ds], stages=SAME_FINAL)
    assert simultaneous.status == staged.status == "converged"
    assert [s.name for s in staged.stages] == ["base-and-tool", "all"]
    # the same final free set from a nearer start: the same optimum, far inside the noise
    assert abs(_chi2(staged) - _chi2(simultaneous)) < 1e-3 * _chi2(simultaneous)
    for i, name in enumerate(COMPLIANCES):
        a, b = staged.estimate(name), simultaneous.estimate(name)
        assert abs(a.value - b.value) < 0.05 * b.std
        assert abs(a.value - true["arm"].compliance[i]) < 4 * a.std  # and both recover the truth
    # the paper's two steps hold the tracker and markers at the arm-nominal fit: never a lower cost
    paper = calibrate(LOADED.robot, [ds], stages=PAPER)
    assert paper.status == "converged" and _chi2(paper) >= _chi2(simultaneous) * (1 - 1e-9)
    assert paper.identifiability.rank < simultaneous.identifiability.rank


def test_stage_record_and_messages():
    _, ds, _, _ = _simulate(LOADED, 5)
    res = calibrate(LOADED.robot, [ds], stages=PAPER)
    first, last = res.stages
    assert (first.parameters, first.rank) == (15, 15)  # tracker 6 + three markers 3 x 3
    assert first.free == ("tracker", "markers") and last.fixed == ("tracker", "markers")
    assert first.status == "misfit" and first.sigma2 > 100  # arm nominal: the frames absorb what they can
    assert last.status == res.status and last.rank == res.identifiability.rank
    assert last.cost == pytest.approx(_chi2(res)) and first.cost > last.cost
    assert first.rms("position") > 10 * last.rms("position") and last.rms("orientation") is None
    assert res.iterations == first.iterations + last.iterations
    assert res.before[0].position_rms > first.rms("position")  # ``before``: at stage 1's start, the nominal
    assert "conditional on tracker, markers" in res.messages[0]
    assert not any(e.name.startswith(("tracker", "markers")) for e in res.estimates)


def test_later_stage_starts_from_the_earlier_estimates():
    _, ds, _, _ = _simulate(LOADED, 5)
    one = calibrate(LOADED.robot, [ds], stages=PAPER[:1])
    two = calibrate(LOADED.robot, [ds], stages=PAPER)
    assert set(two.extras) == {"tracker", "markers"}
    for name in two.extras:  # held in stage 2 at stage 1's estimate
        assert np.array_equal(_value(two.extras[name]), _value(one.extras[name]))
    assert not np.array_equal(_value(one.extras["tracker"]), _value(calibrate(LOADED.robot, [ds], GEOMETRY)
                                                                     .extras["tracker"]))


def _value(x):
    return np.asarray(x.as_array() if hasattr(x, "as_array") else x)


def test_staged_outliers_run_every_stage_again():
    _, ds, _, _ = _simulate(LOADED, 5)
    points = ds.measured["p_tracker_marker"].copy()
    points[7, 1] += 0.005  # one marker 5 mm off (250 sigma)
    bad = replace(ds, measured={**ds.measured, "p_tracker_marker": points})
    res = calibrate(LOADED.robot, [bad], stages=PAPER)
    assert [o.sample for o in res.outliers] == [7]
    assert len(res.stages) == 2 and res.status == "converged"


def test_api_errors():
    _, ds, _, _ = _simulate(LOADED, 5)
    with pytest.raises(ModelError, match="not beside 'stages'"):
        calibrate(LOADED.robot, [ds], "kinematic", stages=PAPER)
    with pytest.raises(ModelError, match=r"stages\[1\]\.free: free parameter pattern 'arm\.j9\*' matches no"):
        calibrate(LOADED.robot, [ds], stages=[PAPER[0], Stage(["arm.j9*"])])
    with pytest.raises(ModelError, match=r"stages\[0\]\.fixed: 'tracker' is unknown .* the first stage cannot"):
        calibrate(LOADED.robot, [ds], stages=[Stage(GEOMETRY, fixed=["tracker"])])
    with pytest.raises(ModelError, match=r"stages\[1\]: frees nothing"):
        calibrate(LOADED.robot, [ds], stages=[PAPER[0], Stage(["tracker"], fixed=["tracker", "markers"])])
    with pytest.raises(ModelError, match="names nothing to free"):
        Stage([])


# ------------------------------------------------------------------------------------------ job files
@pytest.fixture(scope="module")
def loaded_folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("staged")
    _, ds, truth, validation = _simulate(LOADED, 5)
    write_simulation(d, ds, truth, validation, LOADED.robot, model="klimchik3r")
    shutil.copy(EXAMPLES / "paper_two_step.yaml", d)
    return d


def _job(folder, name="job.yaml", **changes):
    spec = yaml.safe_load((EXAMPLES / "paper_two_step.yaml").read_text())
    spec.update(changes)
    path = folder / name
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize("stages, match", [
    ([{"free": ["tracker"], "frozen": ["arm.*"]}], r"field stages\[0\]: unknown key\(s\) \['frozen'\]; expected free"),
    ([{"fixed": ["tracker"]}], r"field stages\[0\]: expected .*\(free required\)"),
    ([{"free": ["tracker"]}, {"free": []}], r"field stages\[1\]\.free: empty; a stage frees at least one"),
    ([{"free": ["tracker"]}, {"free": ["tracker"], "fixed": ["tracker", "markers"]}],
     r"field stages\[1\]: frees nothing \(free \['tracker'\], fixed \['tracker', 'markers'\]\)"),
    ([{"free": ["tracker"]}, {"free": ["kinematic", "arm.j7.offset"]}],
     r"field stages\[1\]\.free: free parameter pattern 'arm\.j7\.offset' matches no parameter"),
    ([{"free": ["tracker"]}, {"free": "kinematic", "fixed": ["trakcer"]}],
     r"field stages\[1\]\.fixed: fixed parameter pattern 'trakcer' matches no parameter"),
    ([{"free": "kinematic", "fixed": ["markers"]}], r"field stages\[0\]\.fixed: 'markers' is unknown"),
    ([{"free": "geometry"}], r"field 'stages\[0\]\.free' is 'geometry'; expected offsets or kinematic or elastic"),
    ([{"free": ["tracker"], "name": 3}], r"field stages\[0\]\.name: expected text, found 3"),
    ([], r"field 'stages' must be a non-empty list"),
    ({"free": "kinematic"}, r"field 'stages' must be a non-empty list"),
])
def test_bad_stages_name_file_and_field(loaded_folder, stages, match):
    path = _job(loaded_folder, stages=stages)
    with pytest.raises(DataFormatError, match=match) as err:
        load_job(path)
    assert str(err.value).startswith(f"{path}: field ") and "\n" not in str(err.value)


def test_free_beside_stages_is_refused(loaded_folder):
    path = _job(loaded_folder, free="kinematic")
    with pytest.raises(DataFormatError, match=r"field 'free': with 'stages', give 'free' in each stage"):
        load_job(path)
    path = _job(loaded_folder, solver={"method": "thesis"})
    with pytest.raises(DataFormatError, match=r"field 'stages' needs kincal's solver"):
        load_job(path)


def test_bad_stage_on_the_command_line(loaded_folder, tmp_path, capsys):
    path = _job(loaded_folder, "cli.yaml", stages=[{"free": ["tracker"]}, {"free": ["kinematic", "arm.j7*"]}])
    assert main(["calibrate", str(path), "-o", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out" / "result.yaml").exists()
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(err) == 1 and str(path) in err[0] and "stages[1].free" in err[0]


def test_paper_two_step_example(loaded_folder, tmp_path, capsys):
    """docs/examples/staged/paper_two_step.yaml on the data of ``kincal simulate klimchik3r_loaded_markers``."""
    job = load_job(loaded_folder / "paper_two_step.yaml")
    assert [s.name for s in job.stages] == ["base-and-tool", "geometry-and-compliance"]
    assert main(["calibrate", str(loaded_folder / "paper_two_step.yaml"), "-o", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "2 stages" in printed and "geometry-and-compliance" in printed and "stages (position mm" in printed
    report = yaml.safe_load((tmp_path / "out" / "result.yaml").read_text())
    first, last = report["stages"]
    assert first["name"] == "base-and-tool" and first["free"] == ["tracker", "markers"] and first["fixed"] == []
    assert first["status"] == "misfit" and last["status"] == report["status"] == "converged"
    assert last["rank"] == report["rank"] and last["fixed"] == ["tracker", "markers"]
    assert last["position_mm_rms"] < 0.1 < first["position_mm_rms"]
    assert last["residuals"][0]["experiment"] == "klimchik3r-loaded-markers"


def test_single_solve_reports_no_stages(loaded_folder):
    spec = yaml.safe_load((EXAMPLES / "paper_two_step.yaml").read_text())
    del spec["stages"]
    spec["free"] = GEOMETRY
    path = loaded_folder / "single.yaml"
    path.write_text(yaml.safe_dump(spec))
    res = run_job(load_job(path))
    assert res.stages == () and res.status == "converged"


DUAL = build_scenario(load_scenario("frida_dual_bracket"))


def test_thesis_offsets_then_kinematics_example(tmp_path):
    """docs/examples/staged/thesis_offsets_then_kinematics.yaml on a smaller ``frida_dual_bracket``."""
    _, ds, truth, validation = run(replace(DUAL, options={**DUAL.options, "n": 150}, n_validation=20))
    write_simulation(tmp_path, ds, truth, validation, DUAL.robot, model="frida")
    shutil.copy(EXAMPLES / "thesis_offsets_then_kinematics.yaml", tmp_path)
    res = run_job(load_job(tmp_path / "thesis_offsets_then_kinematics.yaml"))
    offsets, kinematics = res.stages
    assert offsets.free == "offsets" and kinematics.fixed == ("*.offset",)
    assert offsets.parameters == 14 and offsets.sigma2 > 100 * kinematics.sigma2
    assert res.status == "converged" and res.sigma2 < 2
    assert not any(e.name.endswith(".offset") for e in res.estimates)
    note = next(m for m in res.messages if m.startswith("staged solve, 2 stage(s)"))
    assert "conditional on" in note and "left.offsets" in note and "right.offsets" in note


def test_gauge_list_and_cross_validation_with_stages():
    _, ds, _, _ = _simulate(LOADED, 5)
    # the priority glob matches no free coordinate of the first stage: that stage uses min-change
    res = calibrate(LOADED.robot, [ds], stages=PAPER, gauge=["arm.*.offset"], cv=3)
    assert res.status == "converged" and len(res.stages) == 2
    assert res.cross_validation is not None and len(res.cross_validation.folds) == 3
    assert all(f.status == "converged" for f in res.cross_validation.folds)


def test_html_report_lists_the_stages():
    from html.parser import HTMLParser

    from kincal.report.html import report_html

    _, ds, _, _ = _simulate(LOADED, 5)
    res = calibrate(LOADED.robot, [ds], stages=PAPER)
    page = report_html(res, title="staged")
    cells = []

    class Cells(HTMLParser):
        def handle_data(self, data):
            cells.append(data.strip())

    Cells().feed(page)
    assert "Stages" in cells and "1 base-and-tool" in cells and "2 geometry-and-compliance" in cells
    assert "tracker, markers" in cells and "kinematic, elastic" in cells and "misfit" in cells
    assert "Stages" not in report_html(calibrate(LOADED.robot, [ds], GEOMETRY), title="simultaneous")
