"""Verdicts a user can trust (issue #9, findings 3, 5 and 8): a model that does not explain its data is a
``misfit`` with its own exit code, unit mix-ups are caught before solving (files) or reported as degenerate
(in memory), the predicted RMS error includes noise and unexplained model error, one noise rule."""

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from kincal import robots
from kincal.cli import cli, main
from kincal.cli.calibrate_cmds import EXIT_CODES
from kincal.errors import DataFormatError
from kincal.estimation import Problem, calibrate
from kincal.estimation.finalize import STATUSES
from kincal.io.datasets import load_dataset
from kincal.io.jobs import load_job
from kincal.io.results import result_to_dict
from kincal.noise import DEFAULT, Noise, effective
from kincal.simulate import generate_markers, generate_pose, perturb_robot
from kincal.workflow import run_job

DOCS = Path(__file__).resolve().parents[1] / "docs" / "calibration.md"
NOISE = Noise(position=2e-5, joint=3.5e-5)  # a laser tracker's and an encoder's


def _job(directory: Path, model: str, validation: str, free: str = "offsets") -> Path:
    path = directory / f"job_{free}.yaml"
    path.write_text(yaml.safe_dump({"format": "kincal-job", "version": 1, "model": model,
                                    "data": [{"manifest": "data.yaml"}],
                                    "validation": [{"manifest": validation}], "free": free}))
    return path


@pytest.fixture(scope="module")
def newcomer(tmp_path_factory):
    """What a new user runs: ``kincal simulate`` of the two built-in Frida scenarios, a job at ``free: offsets``."""
    base = tmp_path_factory.mktemp("newcomer")
    runner = CliRunner()
    jobs = {}
    for scenario in ("frida_clamp_one", "frida_plate4"):
        out = base / scenario
        res = runner.invoke(cli, ["simulate", scenario, "-o", str(out)])
        assert res.exit_code == 0, res.output
        jobs[scenario] = _job(out, "frida", "validation/right.yaml")
    return jobs


@pytest.mark.parametrize("scenario", ["frida_clamp_one", "frida_plate4"])
def test_newcomer_misfit_is_not_converged_nor_trusted_cli(newcomer, scenario, tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["calibrate", str(newcomer[scenario]), "-o", str(out)])
    assert res.exit_code == EXIT_CODES["misfit"] == 4, res.output
    assert "misfit" in res.output and "NO" in res.output and "pos RMS predicted" in res.output
    saved = yaml.safe_load((out / "result.yaml").read_text())
    assert saved["status"] == "misfit" and saved["residual_variance_factor"] > 100
    assert saved["messages"][0].startswith("the model does not explain the data")
    for row in saved["predict"]:
        assert row["trusted"] is False and any("does not explain" in d for d in row["doubts"])
        # the predicted RMS error includes the model error the fit could not explain: the actual within 2x
        assert 0.5 < row["position_mm_rms_actual"] / row["position_mm_rms_predicted"] < 2.0
        assert row["position_mm_model_error"] > 1.0
    assert main(["calibrate", str(newcomer[scenario]), "-o", str(tmp_path / "again"), "--quiet"]) == 4


def test_newcomer_misfit_api(newcomer):
    job = load_job(newcomer["frida_clamp_one"])
    res = run_job(job)
    assert res.status == "misfit" and not res.success
    (name, pred), = res.predictions
    v = res.validation[0]
    assert not pred.trusted and pred.position_rms_predicted > 10 * np.sqrt(np.mean(pred.position_std**2))
    # validation orientation is worse than nominal: said so, by set
    if v.after.orientation_rms > 1.1 * v.before.orientation_rms:
        assert any("worse than the nominal" in d and name in d for d in pred.doubts)
    # the same data through calibrate() directly: the manifest's noise is used (one noise rule)
    direct = calibrate(job.robot, job.datasets, "offsets", validation=job.validation)
    assert direct.status == "misfit" and direct.sigma2 == pytest.approx(res.sigma2, rel=1e-6)
    assert direct.problem.noise[0] == effective(None, job.datasets[0].meta["noise"]) == job.noise[job.datasets[0].name]


@pytest.fixture(scope="module")
def markers_dir(tmp_path_factory):
    """The UR10 tracker scenario written by ``kincal simulate`` (mm and deg in the files)."""
    out = tmp_path_factory.mktemp("mk") / "mk"
    assert CliRunner().invoke(cli, ["simulate", "ur10_tracker_markers", "-o", str(out)]).exit_code == 0
    return out


def _rewrite(src: Path, dst: Path, column=None, factor=1.0, angle=None) -> Path:
    """A copy of the data set with ``column``-prefixed CSV columns scaled, or the manifest's angle unit changed."""
    dst.mkdir()
    (dst / "validation").symlink_to(src / "validation")
    lines = (src / "data.csv").read_text().splitlines()
    head = lines[0].split(",")
    rows = [",".join(repr(float(x) * factor) if column and h.startswith(column) else x
                     for h, x in zip(head, line.split(","))) for line in lines[1:]]
    (dst / "data.csv").write_text("\n".join([lines[0]] + rows) + "\n")
    manifest = (src / "data.yaml").read_text()
    (dst / "data.yaml").write_text(manifest.replace("angle: deg", f"angle: {angle}") if angle else manifest)
    return _job(dst, "ur10", "validation/arm.yaml", "kinematic")


def test_unit_mixups_in_files_are_caught_before_solving(markers_dir, tmp_path, capsys):
    ok = _rewrite(markers_dir, tmp_path / "ok")
    assert main(["calibrate", str(ok), "-o", str(tmp_path / "ok_out"), "--quiet"]) == 0
    metres = _rewrite(markers_dir, tmp_path / "metres", "m", 1e-3)  # marker columns in metres, manifest says mm
    assert main(["calibrate", str(metres), "-o", str(tmp_path / "m_out")]) == 2
    err = capsys.readouterr().err
    (line,) = err.strip().splitlines()  # one line, no traceback
    assert line.startswith("kincal: error:") and "data.csv: columns 'm1.x'..'m3.z'" in line
    assert "units.length ('mm')" in line and "are the columns in 'm'?" in line
    degrees = _rewrite(markers_dir, tmp_path / "degrees", angle="rad")  # joints in degrees, manifest says rad
    assert main(["calibrate", str(degrees), "-o", str(tmp_path / "d_out")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert re.search(r"data\.csv: line \d+, column 'arm\.\w+': expected a joint angle within \+-4 pi rad", line)
    assert "in degrees?" in line
    with pytest.raises(DataFormatError, match="data.csv: columns 'm1.x'..'m3.z'"):
        load_dataset(metres.parent / "data.yaml")
    assert not (tmp_path / "m_out").exists() and not (tmp_path / "d_out").exists()


@pytest.fixture(scope="module")
def ur10_truth():
    ur = robots.load("ur10")
    return ur, perturb_robot(ur, "fine", rng=4)


@pytest.mark.parametrize("kind", ["markers", "pose"])
def test_unit_mixups_in_memory(ur10_truth, kind):
    """Past the loaders (a Dataset built in Python): metres where the data mean mm, or degrees as radians, are
    refused by ``solve`` before solving, naming the data set and field; a smaller scale error that passes that
    check (1/20) collapses the arm and is reported as degenerate, never converged, never trusted."""
    ur, true = ur10_truth
    gen, key = (generate_markers, "p_tracker_marker") if kind == "markers" else (generate_pose, "T_tracker_tool")
    ds, _, val = gen(true, n=60, rng=1, noise=NOISE)

    def scaled(factor):
        m = ds.measured[key].copy()
        if kind == "pose":
            m[:, :3, 3] *= factor
        else:
            m *= factor
        return replace(ds, measured={**ds.measured, key: m})

    with pytest.raises(DataFormatError, match=rf"data set '{ds.name}' \({kind}\): the measured {key} spread"):
        calibrate(ur, [scaled(1e-3)], "kinematic")
    with pytest.raises(DataFormatError, match=rf"data set '{ds.name}'.*reads -?[\d.]+ rad, beyond \+-4 pi"):
        calibrate(ur, [replace(ds, q={a: np.degrees(q) for a, q in ds.q.items()})], "kinematic")
    res = calibrate(ur, [scaled(1 / 20)], "kinematic", validation=list(val.values()))
    assert res.status == "degenerate" and any(x.startswith("degenerate solution") for x in res.messages)
    assert not res.predictions[0][1].trusted
    good = calibrate(ur, [ds], "kinematic", validation=list(val.values()))
    assert good.status == "converged" and good.predictions[0][1].trusted


@pytest.mark.parametrize("case", ["noisy validation", "noise-free validation", "model error"])
def test_predicted_rms_is_honest(case):
    """Actual held-out RMS / ``position_rms_predicted`` in [0.67, 1.5] over seeds: the noise of the held-out
    data dominating, the parameter uncertainty dominating (noise-free held-out data, stated as such), or the
    model error the fit cannot explain (offsets only, the truth has twist errors: a misfit). Where parameter
    uncertainty dominates, each calibration's error is one draw of the parameter error, which a few directions
    carry: the ratio holds for the RMS over the seeds (per seed it spreads from 0.6 to 1.6)."""
    ur = robots.load("ur10")
    ratios, pairs = [], []
    for seed in range(6):
        true = perturb_robot(ur, "fine", rng=seed)
        ds, _, val = generate_markers(true, n=60, rng=10 + seed, noise=NOISE)
        held = [generate_markers(true, n=100, rng=20 + seed, noise=NOISE)[0]] if case == "noisy validation" \
            else list(val.values())
        res = calibrate(ur, [ds], "offsets" if case == "model error" else "kinematic", validation=held)
        pred = res.predictions[0][1]
        assert res.status == ("misfit" if case == "model error" else "converged")
        pairs.append((res.validation[0].after.position_rms, pred.position_rms_predicted))
        ratios.append(pairs[-1][0] / pairs[-1][1])
    if case == "noise-free validation":
        actual, predicted = np.sqrt(np.mean(np.square(pairs), axis=0))
        assert 0.67 <= actual / predicted <= 1.5, ratios
    else:
        assert all(0.67 <= r <= 1.5 for r in ratios), ratios


def test_one_noise_rule():
    """Argument over the data set's stated noise over the default, per quantity, in Problem.build."""
    ur = robots.load("ur10")
    ds, _, _ = generate_pose(ur, n=20, rng=0, noise=Noise(position=3e-5))
    stated = Problem.build(ur, [ds], "offsets").noise[0]
    assert stated.position == 3e-5 and stated.orientation == DEFAULT.orientation and stated.joint == DEFAULT.joint
    given = Problem.build(ur, [ds], "offsets", noise=Noise(joint=1e-6)).noise[0]
    assert given.position == 3e-5 and given.joint == 1e-6
    by_name = Problem.build(ur, [ds], "offsets", noise={ds.name: Noise(position=1e-4)}).noise[0]
    assert by_name.position == 1e-4 and by_name.joint == DEFAULT.joint


@pytest.mark.parametrize("loss", ["cauchy", "huber", "soft_l1"])
def test_robust_loss_variance_factor_and_covariance_follow_the_loss(ur10_truth, loss):
    """10 % of rows 50 mm off: with a robust loss the estimate is fine and so are the variance factor and the
    standard deviations (those of the weighted problem), close to the clean data's."""
    ur, _ = ur10_truth
    true = ur.replace_arm("arm", ur["arm"].replace(offsets=np.full(6, 0.01)))
    ds, _, _ = generate_markers(true, n=80, rng=3, noise=NOISE)
    clean = calibrate(ur, [ds], "offsets")
    m = ds.measured["p_tracker_marker"].copy()
    m[::10] += 0.05
    dirty = replace(ds, measured={**ds.measured, "p_tracker_marker": m})
    assert calibrate(ur, [dirty], "offsets", outliers="keep").sigma2 > 1e4  # least squares: a misfit
    robust = calibrate(ur, [dirty], "offsets", loss=loss, f_scale=3.0, outliers="keep")
    assert robust.status == "converged" and robust.sigma2 < 5 * max(clean.sigma2, 1.0)
    ratio = [r.std / c.std for r, c in zip(robust.estimates, clean.estimates) if c.identifiable]
    assert 0.5 < np.median(ratio) < 3.0
    assert all(abs(r.value - c.value) < 3 * c.std for r, c in zip(robust.estimates, clean.estimates)
               if c.identifiable and r.name.endswith(".offset"))


def test_every_status_has_an_exit_code_and_is_documented():
    text = DOCS.read_text()
    section = text[text.index("## Statuses and exit codes"):]
    assert set(EXIT_CODES) == set(STATUSES) and len(set(EXIT_CODES.values())) == len(EXIT_CODES)
    for status, code in EXIT_CODES.items():
        assert re.search(rf"`{status}`.*\|\s*{code}\s*\|", section), status
    assert re.search(r"\|\s*2\s*\|", section)  # input errors


def test_a_model_worse_than_nominal_on_held_out_data_is_a_misfit():
    """Validation worse after calibration than before is a misfit (issue 9, finding 3), even when the model fits
    its own data: here the held-out data come from the nominal robot itself, which the calibration (from a
    perturbed robot's data) has rightly left."""
    ur = robots.load("ur10")
    offsets = ur["arm"].offsets + np.random.default_rng(3).uniform(-0.01, 0.01, ur["arm"].dof)
    true = ur.replace_arm("arm", ur["arm"].replace(offsets=offsets))  # what level 'offsets' can explain
    ds, _, _ = generate_pose(true, None, n=60, rng=4, noise=Noise(position=1e-5, orientation=1e-5))
    fit = calibrate(ur, [ds], "offsets")
    assert fit.status == "converged"
    _, _, held_out = generate_pose(ur, None, n=40, rng=5)  # validation sets of the nominal robot: it is exact there
    res = calibrate(ur, [ds], "offsets", validation=list(held_out.values()))
    v = res.validation[0]
    assert v.after.position_rms > 1.1 * v.before.position_rms
    assert res.status == "misfit" and res.messages[0].startswith("the calibrated model is worse than the nominal")
    assert not res.predictions[0][1].trusted and EXIT_CODES["misfit"] != 0


def test_an_understated_orientation_prediction_is_said_so(newcomer):
    """The single clamp (finding 3) measures orientation, but every configuration holds the tool at one pose: the
    orientation model error seen there (4.8 deg) does not carry to validation poses over the workspace (12.8 deg
    actual against 5.2 deg predicted). Validation says so: a doubt naming the set and the ratio."""
    res = run_job(load_job(newcomer["frida_clamp_one"]))
    (name, pred), = res.predictions
    v = res.validation[0]
    assert v.after.orientation_rms > 2 * pred.orientation_rms_predicted
    assert any(d.startswith(f"on '{name}' the actual orientation error") and "not to be relied on" in d
               for d in pred.doubts)
    assert not any("actual position error" in d for d in pred.doubts)  # the position prediction holds (1.3x)


def test_orientation_is_not_predicted_when_the_calibration_data_measure_none():
    """Tracker points (no orientation measured) from a truth with twist errors, calibrated at level 'offsets': a
    model error in position. Nothing in the data bounds the orientation error: not predicted (nan), said in
    words, never a confident low number; with the model explaining the data the orientation is predicted."""
    ur = robots.load("ur10")
    true = perturb_robot(ur, "thesis", 3)
    ds, _, val = generate_markers(true, n=60, rng=3, noise=Noise(position=2e-5), n_validation=40)
    res = calibrate(ur, [ds], "offsets", noise=NOISE, validation=[val["arm"]])
    (_, pred), = res.predictions
    assert all(c.name == "position" for c in res.problem.experiments[0].components())
    assert pred.position_model > 10 * 2e-5 and np.isnan(pred.orientation_model)
    assert np.isnan(pred.orientation_rms_predicted) and np.isfinite(pred.position_rms_predicted)
    assert any("an unknown orientation error" in m for m in pred.messages)
    (row,) = result_to_dict(res)["predict"]
    assert row["orientation_deg_rms_predicted"] is None
    exact = calibrate(true, [ds], [], noise=NOISE).predict(val["arm"].q["arm"], "arm")  # the model fits
    assert exact.position_model == 0 and np.isfinite(exact.orientation_rms_predicted)


def test_cv_option_and_job_key(markers_dir, tmp_path):
    """``kincal calibrate --cv K`` and the job's ``solver: {cv: K}``: K folds by configuration in result.yaml
    and on the console, held-out RMS next to the RMS predicted from each fold's training fit."""
    job = _job(markers_dir, "ur10", "validation/arm.yaml", "kinematic")
    res = CliRunner().invoke(cli, ["calibrate", str(job), "-o", str(tmp_path / "cli"), "--cv", "3"])
    assert res.exit_code == 0, res.output
    assert "3-fold cross-validation by configuration" in res.output
    assert "cross-validated model error carried into the predictions" in res.output
    cv = yaml.safe_load((tmp_path / "cli" / "result.yaml").read_text())["cross_validation"]
    assert cv["folds"] == 3 and [f["fold"] for f in cv["per_fold"]] == [0, 1, 2]
    assert all(f["status"] == "converged" and f["position_mm_rms_actual"] > 0 for f in cv["per_fold"])
    assert 0.67 < cv["overall"]["position_mm_rms_actual"] / cv["overall"]["position_mm_rms_predicted"] < 1.5
    keyed = tmp_path / "keyed.yaml"
    keyed.write_text(yaml.safe_dump({**yaml.safe_load(job.read_text()), "solver": {"cv": 3},
                                     "data": [{"manifest": str(markers_dir / "data.yaml")}],
                                     "validation": [{"manifest": str(markers_dir / "validation/arm.yaml")}]}))
    assert main(["calibrate", str(keyed), "-o", str(tmp_path / "keyed"), "--quiet"]) == 0
    again = yaml.safe_load((tmp_path / "keyed" / "result.yaml").read_text())["cross_validation"]
    assert again["overall"] == cv["overall"]
    assert yaml.safe_load((tmp_path / "keyed" / "result.yaml").read_text())["trusted"] is True
    keyed.write_text(keyed.read_text().replace("cv: 3", "cv: 1"))
    assert main(["calibrate", str(keyed), "-o", str(tmp_path / "bad"), "--quiet"]) == 2


def test_untrusted_converged_result_is_no_success():
    """Converged and fitting, but a held direction (j7's offset with an unknown fixture) moves the tool at the
    validation configurations: not trusted, not a success, a message says so; the CLI exits 5."""
    from kincal.cli.calibrate_cmds import UNTRUSTED_EXIT, _exit
    from kincal.simulate import generate_clamp

    fr = robots.load("frida")
    true = fr.replace_arm("right", fr["right"].replace(offsets=np.random.default_rng(0).uniform(-.01, .01, 7)))
    ds, _, val = generate_clamp(true, "right", n=30, rng=1, known_fixture=False)
    res = calibrate(fr, [ds], "offsets", validation=[val["right"]])
    assert res.status == "converged" and not res.trusted and not res.success
    assert res.messages[0].startswith("not trusted: directions the calibration data cannot determine")
    with pytest.raises(SystemExit) as exc:
        _exit(res.status, res.trusted)
    assert exc.value.code == UNTRUSTED_EXIT == 5 and UNTRUSTED_EXIT not in EXIT_CODES.values()
    section = DOCS.read_text()[DOCS.read_text().index("## Statuses and exit codes"):]
    assert re.search(r"`converged`, not trusted.*\|\s*5 \(`UNTRUSTED_EXIT`\)\s*\|", section)
    fine = calibrate(fr, [ds], "offsets")  # no validation: nothing says the model will be used elsewhere
    assert fine.trusted and fine.success
