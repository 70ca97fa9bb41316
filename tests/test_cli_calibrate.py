"""``kincal demo`` and ``kincal calibrate``: end to end, JSON output, never overwriting."""

import json
import sys

import pytest
import yaml

from kincal.cli import main
from kincal.errors import DataFormatError, KincalError
from kincal.estimation import calibrate
from kincal.io.jobs import write_job
from kincal.report import plots
from kincal.report.plots import per_sample_errors
from kincal.robots import load
from kincal.simulate import generate_dual


def test_demo_then_calibrate_its_job(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "-n", "40", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["status"] == "converged" and report["rank"] == 14
    for v in report["validation"]:
        assert v["position_mm_rms_after"] < 0.1 * v["position_mm_rms_before"]
    assert (out / "model.yaml").exists() and (out / "result.yaml").exists() and (out / "job.yaml").exists()
    saved = yaml.safe_load((out / "result.yaml").read_text())
    assert saved["estimates"][0]["name"] == "right.j1.offset" or saved["estimates"][0]["name"].endswith(".offset")

    # refusing to overwrite: one clear line, exit code 2
    assert main(["demo", "-o", str(out), "-n", "40", "--quiet"]) == 2
    assert "file exists; not overwritten" in capsys.readouterr().err

    out2 = tmp_path / "again"
    assert main(["calibrate", str(out / "job.yaml"), "-o", str(out2)]) == 0
    text = capsys.readouterr().out
    assert "converged" in text and "validation on held-out configurations" in text
    assert main(["calibrate", str(out / "job.yaml"), "-o", str(out2), "--quiet"]) == 2


def test_calibrate_reports_bad_job(tmp_path, capsys):
    job = tmp_path / "job.yaml"
    job.write_text("format: kincal-job\nversion: 1\nmodel: frida\ndata: [{manifest: missing.yaml}]\n")
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kincal: error:") and "missing.yaml" in err


def test_demo_without_output_picks_a_free_directory_and_reports_recovery(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "kincal-demo-out").mkdir()
    (tmp_path / "kincal-demo-out" / "result.yaml").write_text("someone else's\n")
    assert main(["demo", "-n", "40"]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "kincal-demo-out" / "result.yaml").read_text() == "someone else's\n"
    assert (tmp_path / "kincal-demo-out-2" / "model.yaml").exists()
    assert "recovery of the simulated truth" in out and "left.j7.offset" in out


def test_thesis_method_from_a_job_is_validated_like_kincal(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "-n", "40", "--quiet"]) == 0
    job = yaml.safe_load((out / "job.yaml").read_text())
    job["solver"] = {"method": "thesis"}
    (out / "thesis.yaml").write_text(yaml.safe_dump(job))
    assert main(["calibrate", str(out / "thesis.yaml"), "-o", str(tmp_path / "thesis")]) in (0, 1)
    text = capsys.readouterr().out
    assert "thesis baseline thesis.dual_offsets" in text and "validation on held-out configurations" in text
    saved = yaml.safe_load((tmp_path / "thesis" / "result.yaml").read_text())
    assert saved["iterations"].endswith(")") and len(saved["validation"]) == 2
    v = saved["validation"][0]
    assert v["position_mm_rms_after"] < v["position_mm_rms_before"]  # the thesis method does improve, if not exactly


def test_calibrate_writes_plots(tmp_path):
    """--plots: residuals, identifiability, uncertainty and prediction PNGs next to the results; a second run
    into the same directory does not replace them."""
    assert main(["demo", "-o", str(tmp_path / "demo"), "-n", "40", "--quiet"]) == 0
    out = tmp_path / "out"
    assert main(["calibrate", str(tmp_path / "demo" / "job.yaml"), "-o", str(out), "--plots", "--quiet"]) == 0
    names = sorted(p.name for p in (out / "plots").iterdir())
    assert names == ["identifiability.png", "prediction.png", "residuals.png", "uncertainty.png"]
    for p in (out / "plots").iterdir():
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    (out / "model.yaml").unlink()
    (out / "result.yaml").unlink()
    assert main(["calibrate", str(tmp_path / "demo" / "job.yaml"), "-o", str(out), "--plots", "--quiet"]) == 2


def test_plots_report_per_sample_errors_before_and_after(tmp_path):
    """The residual plot's numbers: per-sample position errors at the nominal model and at the result."""
    frida = load("frida")
    true = frida
    for a in ("left", "right"):  # offsets only, which the calibration frees
        true = true.replace_arm(a, true[a].replace(offsets=true[a].offsets + 0.02))
    ds, _, _ = generate_dual(true, n=40, rng=2, known_clamp=True)
    res = calibrate(frida, [ds], "offsets")
    ((name, before, after),) = per_sample_errors(res)
    assert name == ds.name and before.shape == after.shape == (40,)
    assert before.min() > 1e-3 and after.max() < 1e-9  # millimetres of error before, exact after (noise-free)


def test_plots_without_matplotlib_say_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if not installed
    with pytest.raises(KincalError, match=r'pip install "kincal\[plot\]"'):
        plots.write_plots(None, tmp_path / "p")


def test_write_job_writes_what_load_job_reads_and_never_overwrites(tmp_path):
    path = write_job(tmp_path / "job.yaml", name="j", model="frida", data=["data.yaml"],
                     validation=["validation/left.yaml"], free=["offsets", "clamp"])
    assert yaml.safe_load(path.read_text()) == {
        "format": "kincal-job", "version": 1, "name": "j", "model": "frida", "data": [{"manifest": "data.yaml"}],
        "validation": [{"manifest": "validation/left.yaml"}], "free": ["offsets", "clamp"]}
    with pytest.raises(DataFormatError, match="job.yaml: file exists; not overwritten"):
        write_job(path, name="k", model="ur10", data=["other.yaml"])
    assert yaml.safe_load(path.read_text())["name"] == "j"
