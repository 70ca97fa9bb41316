"""The HTML report (issue #12, item 4): self-contained, the verdict first, parsed in a test; rendered in
headless Chromium (a screenshot that is not blank, and the rendered text) when chromium is installed."""

from __future__ import annotations

import base64
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest
import yaml

from kincal import robots
from kincal.estimation import Noise, calibrate
from kincal.simulate import generate_markers, perturb_robot, random_configurations

pytest.importorskip("matplotlib")
from kincal.report.html import report_html  # noqa: E402

UR10 = robots.load("ur10")
ARM = next(iter(UR10.arms))


class _Parsed(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.text, self.images, self.headings, self._h = [], [], [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag in ("h1", "h2", "h3"):
            self._h = tag

    def handle_endtag(self, tag):
        if tag == self._h:
            self._h = None

    def handle_data(self, data):
        self.text.append(data)
        if self._h:
            self.headings.append(data.strip())


@pytest.fixture(scope="module")
def report():
    true = perturb_robot(UR10, "fine", rng=1)
    ds, _, val = generate_markers(true, ARM, n=60, rng=2, noise=Noise(position=5e-5))
    res = calibrate(UR10, [ds], "offsets", noise=Noise(position=5e-5), validation=[val[ARM]])
    q = random_configurations(UR10[ARM], 150, np.random.default_rng(0))
    prov = {"job": "job.yaml", "kincal": "0.1.0", "date": "2026-11-24",
            "inputs": [{"file": "data/markers.csv", "sha256": "ab" * 32}]}
    return res, report_html(res, title="UR10 tracker", workspace={ARM: q}, provenance=prov)


def test_report_is_self_contained_with_the_verdict_first(report):
    res, text = report
    p = _Parsed()
    p.feed(text)
    assert not any(s for s in p.images if not s.startswith("data:image/png;base64,"))  # nothing external
    assert "link" not in p.tags and "script" not in p.tags
    for src in p.images:
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(p.images) >= 4  # uncertainty, residuals, prediction, spectrum, accuracy map
    assert p.headings[:3] == ["UR10 tracker", "Summary", p.headings[2]] and p.headings[2].startswith("What cannot")
    body = "".join(p.text)
    assert body.index(res.status) < body.index("Estimates") < body.index("Provenance")
    assert f"trusted: {'yes' if res.trusted else 'no'}" in " ".join(body.split())
    assert "Predicted accuracy over the workspace" in p.headings and "ab" * 32 in body
    for e in res.estimates:
        assert e.name in body
    if res.gauge is not None:  # the determined change and gauge move in the named gauge
        assert "determined change" in body and "gauge move" in body and res.gauge.description in body


def test_report_renders_in_headless_chromium(report, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium not installed (Debian package 'chromium'; .ci/run installs it)")
    page = tmp_path / "report.html"
    page.write_text(report[1], encoding="utf-8")
    shot = tmp_path / "shot.png"
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"]
    subprocess.run([chromium, *flags, "--window-size=1200,1600", f"--screenshot={shot}", page.as_uri()],
                   check=True, capture_output=True, timeout=120)
    plt = pytest.importorskip("matplotlib.pyplot")
    img = plt.imread(shot)
    assert img.shape[0] >= 1000 and img.std() > 0.05  # not blank
    dom = subprocess.run([chromium, *flags, "--dump-dom", page.as_uri()], check=True, capture_output=True,
                         text=True, timeout=120).stdout
    assert "UR10 tracker" in dom and "trusted" in dom and "What cannot be identified" in dom


def test_cli_report_and_plot_recompute_from_the_recorded_job(tmp_path, monkeypatch, capsys):
    from kincal.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "ur10_tracker_markers", "-o", "sim", "--quiet"]) == 0
    (tmp_path / "job.yaml").write_text("format: kincal-job\nversion: 1\nmodel: ur10\ndata: [sim/data.yaml]\n"
                                       "validation: [sim/validation/arm.yaml]\nfree: offsets\n")
    main(["calibrate", "job.yaml", "-o", "res", "--quiet"])
    prov = yaml.safe_load((tmp_path / "res" / "result.yaml").read_text())["provenance"]
    assert prov["job"] == str(tmp_path / "job.yaml") and len(prov["inputs"]) >= 3
    monkeypatch.chdir(tmp_path / "sim")  # absolute paths: reported from anywhere
    assert main(["report", str(tmp_path / "res"), "--workspace", "50"]) == 0
    p = _Parsed()
    p.feed((tmp_path / "res" / "report.html").read_text())
    assert "Provenance" in p.headings and str(tmp_path / "job.yaml") in "".join(p.text)
    assert main(["report", str(tmp_path / "res")]) == 2  # no overwrite
    assert main(["plot", str(tmp_path / "res")]) == 0
    assert sorted(f.name for f in (tmp_path / "res" / "plots").iterdir()) == [
        "identifiability.png", "prediction.png", "residuals.png", "uncertainty.png"]
    capsys.readouterr()
    (tmp_path / "sim" / "data.csv").write_text((tmp_path / "sim" / "data.csv").read_text() + "\n")
    assert main(["report", str(tmp_path / "res"), "-o", str(tmp_path / "r2.html")]) == 2
    err = capsys.readouterr().err
    assert "changed since this result was computed" in err and err.count("\n") == 1
    assert not (tmp_path / "r2.html").exists()


def test_report_and_plot_without_matplotlib_are_one_line_before_any_work(tmp_path, monkeypatch, capsys):
    import sys

    from kincal.cli import main
    from kincal.cli import report_cmds

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if not installed
    monkeypatch.setattr(report_cmds, "recompute", lambda *a, **k: pytest.fail("recomputed before refusing"))
    for command, words in (("report", "the report's plots need matplotlib"), ("plot", "plots need matplotlib")):
        assert main([command, str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert words in err and "--plots" not in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []
