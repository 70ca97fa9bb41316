"""Outlying configurations (issue #9, finding 4): found after a robust pass, listed by row, left out by default."""

import numpy as np
import pytest
import yaml

from kincal.cli import main
from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.jobs import load_job, write_job
from kincal.io.results import result_to_dict
from kincal.robots import load
from kincal.simulate import Noise
from kincal.simulate.generators import generate_markers

UR10 = load("ur10")
SIGMA = 2e-5  # 0.02 mm tracker noise
# identifiable offsets of the UR10 at level 'offsets' with an unknown tracker (shoulder_pan and wrist_3 are gauges)
OFFSETS = [f"arm.{j}.offset" for j in ("shoulder_lift", "elbow", "wrist_1", "wrist_2")]


def _markers(seed: int, n: int = 160) -> Dataset:
    rng = np.random.default_rng(seed)
    true = UR10.replace_arm("arm", UR10["arm"].replace(offsets=rng.uniform(-0.01, 0.01, 6)))
    ds, _, _ = generate_markers(true, n=n, rng=seed, noise=Noise(position=SIGMA), n_validation=1)
    return ds


def _corrupt(ds: Dataset, fraction: float, how: str, seed: int) -> tuple[Dataset, set[int]]:
    """``ds`` with ``fraction`` of its rows replaced: all-zero tracker readings or one marker moved 50 mm."""
    rng = np.random.default_rng(100 + seed)
    bad = rng.choice(ds.size, max(1, round(fraction * ds.size)), replace=False)
    p = np.array(ds.measured["p_tracker_marker"])
    if how == "zero":
        p[bad] = 0.0
    else:
        d = rng.standard_normal((len(bad), 3))
        p[bad, rng.integers(0, p.shape[1], len(bad))] += 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True)
    return Dataset(ds.kind, ds.robot, ds.arms, ds.q, {"p_tracker_marker": p}, dict(ds.known), ds.name,
                   dict(ds.meta), dict(ds.frames)), set(bad.tolist())


def test_clean_data_rejects_nothing_and_matches_keep():
    ds = _markers(1)
    default = calibrate(UR10, [ds], "offsets")
    kept = calibrate(UR10, [ds], "offsets", outliers="keep")
    assert default.outliers == () and default.status == "converged"
    assert default.sigma2 == kept.sigma2
    for a, b in zip(default.estimates, kept.estimates):
        assert a.value == b.value and (a.std == b.std or not a.identifiable)


@pytest.mark.parametrize("how", ["zero", "50mm"])
@pytest.mark.parametrize("fraction", [0.01, 0.05, 0.10])
def test_injected_outliers_found_and_estimates_recovered(fraction, how):
    true_pos = found_pos = found = 0
    for seed in (1, 2, 3):
        ds = _markers(seed)
        clean = calibrate(UR10, [ds], "offsets")
        bad_ds, bad = _corrupt(ds, fraction, how, seed)
        res = calibrate(UR10, [bad_ds], "offsets")
        rows = {o.sample for o in res.outliers}
        true_pos += len(rows & bad)
        found_pos += len(bad)
        found += len(rows)
        assert res.status == "converged"
        assert not any("does not explain the data" in m for m in res.messages)
        assert sum(a.samples for a in res.after) == ds.size - len(rows)
        for name in OFFSETS:
            e, c = res.estimate(name), clean.estimate(name)
            assert abs(e.value - c.value) < 2 * c.std, (seed, name, e.value, c.value, c.std)
    assert true_pos / found >= 0.95 and true_pos / found_pos >= 0.95


def test_keep_leaves_them_in_and_a_bad_choice_is_refused():
    bad_ds, bad = _corrupt(_markers(2), 0.05, "zero", 2)
    res = calibrate(UR10, [bad_ds], "offsets", outliers="keep")
    assert res.outliers == () and res.status == "misfit"
    strict = calibrate(UR10, [bad_ds], "offsets", outliers=1e-12)
    assert {o.sample for o in strict.outliers} == bad
    with pytest.raises(ModelError, match="outliers must be"):
        calibrate(UR10, [bad_ds], "offsets", outliers="drop")


def _files(tmp_path, outliers_key=None):
    """A marker data set with three all-zero tracker rows written to CSV, and a job on it."""
    ds, bad = _markers(4, n=120), {7, 40, 99}
    p = np.array(ds.measured["p_tracker_marker"])
    p[sorted(bad)] = 0.0
    ds = Dataset(ds.kind, ds.robot, ds.arms, ds.q, {"p_tracker_marker": p}, dict(ds.known), "tracker",
                 {"noise": ds.meta["noise"]}, dict(ds.frames))
    manifest = write_dataset(ds, tmp_path / "tracker.yaml", UR10, model="ur10", length="mm")
    job = write_job(tmp_path / "job.yaml", name="outliers", model="ur10", data=[manifest.name])
    if outliers_key is not None:
        top = yaml.safe_load(job.read_text())
        top["outliers"] = outliers_key
        job.write_text(yaml.safe_dump(top))
    return manifest, job, bad


def test_loader_records_csv_lines_and_subsets_keep_them(tmp_path):
    manifest, _, _ = _files(tmp_path)
    ds = load_dataset(manifest)
    assert list(ds.meta["lines"][:3]) == [2, 3, 4] and ds.meta["file"].endswith("tracker.csv")
    assert list(ds.subset([5, 1]).meta["lines"]) == [7, 3]


def test_job_lists_rejected_rows_with_their_csv_lines(tmp_path, capsys):
    _, job, bad = _files(tmp_path)
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "3 configuration(s) left out as outliers" in text and "tracker.csv: line 9:" in text
    saved = yaml.safe_load((tmp_path / "out" / "result.yaml").read_text())
    rows = saved["outliers"]
    assert [r["line"] for r in rows] == [i + 2 for i in sorted(bad)]  # header = line 1
    assert all(r["experiment"] == "tracker" and r["file"].endswith("tracker.csv") for r in rows)
    assert all(r["standardized_residual"] > 100 for r in rows)
    # the loader warns (not an error) about tracker points exactly at the origin
    (warning,) = saved["data_warnings"]
    assert "line(s) 9, 42, 101" in warning and "origin" in warning and "warning:" in text


def test_loader_warns_on_a_row_repeated_exactly(tmp_path):
    manifest, _, _ = _files(tmp_path)
    csv = manifest.with_suffix(".csv")
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines + [lines[5]]) + "\n")
    warnings = load_dataset(manifest).meta["warnings"]
    assert any(f"line(s) {len(lines) + 1}: repeats an earlier row exactly" in w for w in warnings)


def test_job_keep_and_threshold_keys(tmp_path):
    _, job, _ = _files(tmp_path, "keep")
    assert load_job(job).outliers == "keep"
    (tmp_path / "b").mkdir()
    _, job, _ = _files(tmp_path / "b", {"threshold": 1e-9})
    assert load_job(job).outliers == 1e-9
    (tmp_path / "c").mkdir()
    _, job, _ = _files(tmp_path / "c", {"threshold": 2})
    with pytest.raises(DataFormatError, match="outliers"):
        load_job(job)


def test_validation_rows_follow_the_same_rule():
    """Outlying rows in a validation set (noise stated) are flagged by the calibration data's rule, listed and
    left out of the validation errors, which also say the RMS with them; noise-free sets have none to find."""
    rng = np.random.default_rng(5)
    true = UR10.replace_arm("arm", UR10["arm"].replace(offsets=rng.uniform(-0.01, 0.01, 6)))
    ds, _, val = generate_markers(true, n=80, rng=5, noise=Noise(position=SIGMA), n_validation=60)
    v = val["arm"]
    clean = calibrate(UR10, [ds], "offsets", validation=[v])
    assert clean.validation_outliers == () and clean.validation_all == ()  # noise-free: nothing standardizes
    noisy = Dataset(v.kind, v.robot, v.arms, v.q, {"p_tracker_marker": v.measured["p_tracker_marker"]
                                                   + rng.normal(0, SIGMA, v.measured["p_tracker_marker"].shape)},
                    dict(v.known), v.name, {**v.meta, "noise": {"position_m": SIGMA}}, dict(v.frames))
    dirty, bad = _corrupt(noisy, 0.05, "zero", 3)
    res = calibrate(UR10, [ds], "offsets", validation=[dirty])
    assert {o.sample for o in res.validation_outliers} == bad
    assert all(o.experiment == v.name for o in res.validation_outliers)
    (kept,), (every,) = res.validation, res.validation_all
    assert kept.samples == v.size - len(bad) and every.samples == v.size
    assert kept.after.position_rms < 0.1e-3 < every.after.position_rms  # zeros are metres off
    assert any(m.startswith(f"validation set '{v.name}': {len(bad)} row(s) beyond the outlier rule")
               for m in res.messages)
    report = result_to_dict(res)
    assert len(report["validation_outliers"]) == len(bad) and report["validation_all_rows"][0]["samples"] == v.size
    kept_all = calibrate(UR10, [ds], "offsets", validation=[dirty], outliers="keep")
    assert kept_all.validation_outliers == () and kept_all.validation[0].samples == v.size
