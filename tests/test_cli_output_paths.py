"""Output paths that cannot be written give kincal's one-line error naming the path (issue #10), for every
command that writes: simulate, convert-log, demo."""

import os

import pytest

from kincal.cli import main


def _blocked(tmp_path):
    """A path under a regular file: no folder can be made there."""
    f = tmp_path / "a_file"
    f.write_text("not a folder\n")
    return f / "out"


def _log(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("t," + ",".join(f"arm.c{i + 1}" for i in range(6)) + "\n"
                 + "\n".join(f"{0.004 * k}," + ",".join("0.1" for _ in range(6)) for k in range(30)) + "\n")
    return p


@pytest.mark.parametrize("command", ["simulate", "convert-log", "demo"])
def test_unwritable_output_is_one_line_naming_the_path(tmp_path, capsys, command):
    out = _blocked(tmp_path)
    argv = {"simulate": ["simulate", "ur10_tracker_markers", "-o", str(out), "--quiet"],
            "convert-log": ["convert-log", str(_log(tmp_path)), "-m", "ur10", "-o", str(out / "q.csv")],
            "demo": ["demo", "-o", str(out), "--samples", "40"]}[command]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("kincal: error: ") and "a_file" in err and "\n" not in err
    assert "Traceback" not in err


def test_convert_log_period_zero_is_refused_not_replaced(tmp_path, capsys):
    code = main(["convert-log", str(_log(tmp_path)), "-m", "ur10", "-o", str(tmp_path / "q.csv"), "--period-s", "0"])
    assert code == 2 and "--period-s: expected a finite number > 0" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "q.csv")


def test_output_into_the_current_folder(tmp_path, monkeypatch):
    """``-o .`` has no name of its own: the temporary goes beside the folder under its real name, and nothing
    but the output is left, in the folder or above it."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["simulate", "ur10_tracker_markers", "-o", ".", "--quiet"]) == 0
    assert sorted(os.listdir(work)) == ["data.csv", "data.yaml", "truth", "validation"]
    assert os.listdir(tmp_path) == ["work"]
    assert main(["convert-log", str(_log(tmp_path)), "-m", "ur10", "-o", "q.csv"]) == 0
    assert sorted(os.listdir(work)) == ["data.csv", "data.yaml", "q.csv", "truth", "validation"]


def test_a_path_of_the_wrong_kind_is_one_line_for_every_command(tmp_path, capsys):
    """A folder where a file is expected and the reverse: kincal's own one-line error (click's multi-line usage
    error before), exit 2, nothing written, never a traceback."""
    f = tmp_path / "afile"
    f.write_text("")
    d = tmp_path / "adir"
    d.mkdir()
    cases = [["calibrate", str(d), "-o", str(tmp_path / "x")], ["simulate", "frida_clamp_one", "-o", str(f)],
             ["convert-log", str(d), "-m", "frida", "-o", str(tmp_path / "x.csv")],
             ["report", str(f)], ["plot", str(d)], ["design", str(f), "--next", "3", "-o", str(tmp_path / "y")],
             ["design", str(d), "-n", "3", "-o", str(tmp_path / "y")], ["analyze", str(d)],
             ["import", str(d), "--base-link", "a", "--tip-link", "b", "-o", str(tmp_path / "m.yaml")],
             ["export", "ur10", "--to", "urdf", "-o", str(d)]]
    for args in cases:
        assert main(args) == 2, args
        err = capsys.readouterr().err.strip()
        assert err.startswith("kincal: error: ") and "\n" not in err, (args, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile"]


def test_calibrate_and_design_replace_a_previous_output_only_with_overwrite(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "frida_dual_bracket", "-o", "sim", "--quiet"]) == 0
    (tmp_path / "job.yaml").write_text("format: kincal-job\nversion: 1\nmodel: frida\ndata: [sim/data.yaml]\n")
    first = main(["calibrate", "job.yaml", "-o", "r", "--quiet"])
    before = os.stat(tmp_path / "r" / "result.yaml").st_ino
    assert main(["calibrate", "job.yaml", "-o", "r", "--quiet"]) == 2
    assert "not overwritten" in capsys.readouterr().err
    assert main(["calibrate", "job.yaml", "-o", "r", "--quiet", "--overwrite"]) == first
    assert os.stat(tmp_path / "r" / "result.yaml").st_ino != before  # a new file moved in whole
    assert "provenance" in (tmp_path / "r" / "result.yaml").read_text()
    assert sorted(os.listdir(tmp_path / "r")) == ["model.yaml", "result.yaml"]
    assert main(["design", "frida_dual_bracket", "-n", "30", "--pool", "60", "-o", "d"]) == 0
    assert main(["design", "frida_dual_bracket", "-n", "30", "--pool", "60", "-o", "d"]) == 2
    assert main(["design", "frida_dual_bracket", "-n", "31", "--pool", "60", "-o", "d", "--overwrite"]) == 0
    assert len((tmp_path / "d" / "targets.csv").read_text().splitlines()) == 32
