"""All-or-nothing outputs (issue #10, "Atomic writes"): the staging module, every writing command interrupted
by an exception, and ``kincal calibrate --plots`` killed by SIGINT and SIGKILL at random moments."""

import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

import kincal.io.atomic as atomic
from kincal.cli import calibrate_cmds, main
from kincal.errors import DataFormatError
from kincal.io.atomic import output_directory, output_file
from kincal.io.models import load_robot

STALE = re.compile(r"^\.out\.kincal-tmp-(\d+)-[0-9a-f]+$")


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _write(folder, name, text):
    (folder / name).parent.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)


# ------------------------------------------------------------------------------------------ the staging module


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_an_exception_inside_leaves_nothing(tmp_path, error):
    target = tmp_path / "new" / "deeper" / "out"
    with pytest.raises(error):
        with output_directory(target, names=("a.yaml",)) as stage:
            _write(stage.path, "a.yaml", "half")
            assert stage.path.parent == target.parent and stage.path.name.startswith(".out.kincal-tmp-")
            raise error()
    assert list(tmp_path.iterdir()) == []  # the folders it made for the target are gone too


def test_an_interrupt_held_back_while_the_temporary_is_made_still_removes_it(tmp_path, monkeypatch):
    """SIGINT while the temporary folder is being made waits until it exists, and then must not strand it."""
    real = atomic._new_stage

    def interrupted(target, inside_ok):
        stage = real(target, inside_ok)
        os.kill(os.getpid(), signal.SIGINT)  # held back: arrives when the signals are released
        return stage

    monkeypatch.setattr(atomic, "_new_stage", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with output_directory(tmp_path / "out"):
            pytest.fail("the interrupt must come before the body")
    assert os.listdir(tmp_path) == []


def _interrupt_during_the_move(monkeypatch):
    real = atomic._commit

    def commit_interrupted(*args, **kw):
        os.kill(os.getpid(), signal.SIGINT)  # held back until the move is done
        real(*args, **kw)

    monkeypatch.setattr(atomic, "_commit", commit_interrupted)


def test_an_interrupt_during_the_move_waits_for_it(tmp_path, monkeypatch):
    _interrupt_during_the_move(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        with output_directory(tmp_path / "out", names=("a.yaml", "b.yaml")) as stage:
            _write(stage.path, "a.yaml", "a")
            _write(stage.path, "b.yaml", "b")
    assert os.listdir(tmp_path) == ["out"] and sorted(os.listdir(tmp_path / "out")) == ["a.yaml", "b.yaml"]


def test_a_new_folder_appears_whole(tmp_path):
    target = tmp_path / "out"
    with output_directory(target, names=("a.yaml", "sub"), last="a.yaml") as stage:
        _write(stage.path, "a.yaml", "a")
        _write(stage.path, "sub/b.csv", "b")
        assert not target.exists()
    assert sorted(os.listdir(tmp_path)) == ["out"]
    assert (target / "a.yaml").read_text() == "a" and (target / "sub" / "b.csv").read_text() == "b"
    assert stage.final(stage.path / "sub" / "b.csv") == target / "sub" / "b.csv"


def test_an_output_folder_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "out").write_text("a file")
    with pytest.raises(DataFormatError, match=r"out: exists and is not a directory; expected an output directory"):
        with output_directory(tmp_path / "out"):
            pytest.fail("must not get here")
    with pytest.raises(DataFormatError, match=r"out: exists and is not a directory; expected a folder"):
        with output_directory(tmp_path / "out" / "deeper"):
            pytest.fail("must not get here")
    assert os.listdir(tmp_path) == ["out"]


def test_existing_entries_are_refused_before_anything_is_written(tmp_path):
    _write(tmp_path, "out/a.yaml", "old")
    with pytest.raises(DataFormatError, match=r"out/a\.yaml: file exists; not overwritten"):
        with output_directory(tmp_path / "out", names=("a.yaml",)):
            pytest.fail("must not get here")
    assert sorted(os.listdir(tmp_path)) == ["out"] and os.listdir(tmp_path / "out") == ["a.yaml"]


def test_overwrite_keeps_the_old_output_until_the_end(tmp_path):
    target = tmp_path / "out"
    for name, text in (("a.yaml", "old a"), ("sub/b.csv", "old b"), ("gone/c", "old c"), ("mine.txt", "user")):
        _write(target, name, text)
    with output_directory(target, names=("a.yaml", "sub", "gone"), overwrite=True, last="a.yaml") as stage:
        _write(stage.path, "a.yaml", "new a")
        _write(stage.path, "sub/d.csv", "new d")
        assert (target / "a.yaml").read_text() == "old a" and (target / "gone" / "c").exists()
    assert (target / "a.yaml").read_text() == "new a"
    assert os.listdir(target / "sub") == ["d.csv"]  # a replaced folder is replaced as a whole
    assert not (target / "gone").exists()  # an entry of the old output this run does not write
    assert (target / "mine.txt").read_text() == "user"  # not an entry of the output: untouched
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_overwrite_then_an_exception_leaves_the_old_output(tmp_path):
    target = tmp_path / "out"
    _write(target, "a.yaml", "old a")
    with pytest.raises(KeyboardInterrupt):
        with output_directory(target, names=("a.yaml",), overwrite=True) as stage:
            _write(stage.path, "a.yaml", "new a")
            raise KeyboardInterrupt
    assert (target / "a.yaml").read_text() == "old a" and sorted(os.listdir(tmp_path)) == ["out"]


def test_the_completion_marker_leaves_first_and_arrives_last(tmp_path, monkeypatch):
    target = tmp_path / "out"
    for name in ("a.yaml", "b.yaml", "result.yaml"):
        _write(target, name, "old")
    moves, rename = [], os.rename
    monkeypatch.setattr(atomic.os, "rename", lambda a, b: (moves.append((a.name, b.parent.name)), rename(a, b)))
    with output_directory(target, names=("a.yaml", "b.yaml", "result.yaml"), overwrite=True,
                          last="result.yaml") as stage:
        for name in ("a.yaml", "result.yaml", "b.yaml"):
            _write(stage.path, name, "new")
    assert moves[0] == ("result.yaml", ".old") and moves[-1] == ("result.yaml", "out")
    assert [(target / n).read_text() for n in ("a.yaml", "b.yaml", "result.yaml")] == ["new"] * 3


def test_a_failing_move_puts_everything_back(tmp_path, monkeypatch):
    target = tmp_path / "out"
    _write(target, "a.yaml", "old a")
    _write(target, "b.yaml", "old b")
    rename, failures = os.rename, [OSError(28, "No space left on device")]

    def flaky(a, b):
        if a.name == "b.yaml" and b.parent == target and failures:
            raise failures.pop()
        rename(a, b)

    monkeypatch.setattr(atomic.os, "rename", flaky)
    with pytest.raises(DataFormatError, match="cannot move the output into place: No space left on device"):
        with output_directory(target, names=("a.yaml", "b.yaml"), overwrite=True) as stage:
            _write(stage.path, "a.yaml", "new a")
            _write(stage.path, "b.yaml", "new b")
    assert [(target / n).read_text() for n in ("a.yaml", "b.yaml")] == ["old a", "old b"]
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead, alive = _dead_pid(), os.getppid()
    for pid in (dead, alive):
        _write(tmp_path, f".out.kincal-tmp-{pid}-0a1b2c3d/result.yaml", "cut off")
    _write(tmp_path, ".other.kincal-tmp-%d-0a1b2c3d/x" % dead, "another target's")
    with output_directory(tmp_path / "out", names=("a.yaml",)) as stage:
        _write(stage.path, "a.yaml", "a")
    left = sorted(os.listdir(tmp_path))
    assert left == sorted(["out", f".out.kincal-tmp-{alive}-0a1b2c3d", f".other.kincal-tmp-{dead}-0a1b2c3d"])


def test_a_read_only_parent_puts_the_temporary_inside_an_existing_target(tmp_path, monkeypatch):
    """``-o .`` where the folder above may not be written: calibrate's results carry no relative paths, so they
    may be staged inside; a simulation's manifest does (its model reference), so it refuses instead."""
    target = tmp_path / "out"
    _write(target, "data.yaml", "mine")
    mkdir = type(target).mkdir

    def refuse_beside(self, *args, **kw):
        if self.parent == tmp_path and self.name.startswith(".out.kincal-tmp-"):
            raise PermissionError(13, "Permission denied")
        return mkdir(self, *args, **kw)

    monkeypatch.setattr(type(target), "mkdir", refuse_beside)
    with output_directory(target, names=("a.yaml",)) as stage:
        assert stage.path.parent == target
        _write(stage.path, "a.yaml", "a")
    assert sorted(os.listdir(target)) == ["a.yaml", "data.yaml"]
    with pytest.raises(DataFormatError, match="cannot create the temporary output folder beside out: Permission"):
        with output_directory(target, names=("b.yaml",), inside_ok=False):
            pytest.fail("must not get here")


def test_undo_removes_what_a_first_step_added(tmp_path):
    target = tmp_path / "out"
    _write(target, "mine.txt", "user")
    with output_directory(target, names=("a.yaml",)) as stage:
        _write(stage.path, "a.yaml", "a")
    stage.undo()
    assert os.listdir(target) == ["mine.txt"]


def test_a_single_file_is_replaced_only_when_complete(tmp_path):
    target = tmp_path / "q.csv"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with output_file(target, overwrite=True) as temp:
            temp.write_text("half")
            raise KeyboardInterrupt
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["q.csv"]
    with pytest.raises(DataFormatError, match="exists; refusing to overwrite it"):
        with output_file(target):
            pytest.fail("must not get here")
    with output_file(target, overwrite=True) as temp:
        temp.write_text("new")
        assert target.read_text() == "old"
    assert target.read_text() == "new" and os.listdir(tmp_path) == ["q.csv"]
    with pytest.raises(DataFormatError, match="is a directory; expected an output file"):
        with output_file(tmp_path, overwrite=True):
            pytest.fail("must not get here")


# ------------------------------------------------------------------------------------------ the commands


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """A small real calibration job: the UR10 tracker scenario, simulated, with its validation set."""
    folder = tmp_path_factory.mktemp("job")
    assert main(["simulate", "ur10_tracker_markers", "-o", str(folder / "sim"), "--quiet"]) == 0
    path = folder / "job.yaml"
    path.write_text(yaml.safe_dump({"format": "kincal-job", "version": 1, "name": "kill-test", "model": "ur10",
                                    "data": [{"manifest": "sim/data.yaml"}],
                                    "validation": [{"manifest": "sim/validation/arm.yaml"}], "free": "kinematic"}))
    return path


def test_an_interrupt_while_writing_plots_leaves_no_output(tmp_path, job, monkeypatch):
    """SIGINT during --plots used to leave model.yaml and result.yaml with a partial plots/."""
    import kincal.workflow.outputs as outputs

    def one_plot_then_interrupt(result, folder):
        folder.mkdir()
        (folder / "residuals.png").write_bytes(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "write_plots", one_plot_then_interrupt)
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out"), "--plots", "--quiet"]) == 130
    assert os.listdir(tmp_path) == []


def test_sigterm_while_writing_unwinds_and_leaves_no_output(tmp_path, job, monkeypatch):
    """SIGTERM (what process managers and ``timeout`` send) unwinds like an interrupt: exit 143, nothing left."""
    import kincal.workflow.outputs as outputs

    real = outputs.write_results

    def terminated_while_writing(result, folder, **kw):
        real(result, folder, **kw)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends
        pytest.fail("SIGTERM did not stop the command")

    monkeypatch.setattr(outputs, "write_results", terminated_while_writing)
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out"), "--quiet"]) == 143
    assert os.listdir(tmp_path) == []
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # main() puts the previous handler back


def test_plots_without_matplotlib_are_refused_before_the_solve(tmp_path, job, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if not installed
    monkeypatch.setattr(calibrate_cmds, "run_job", lambda *a, **k: pytest.fail("solved before refusing"))
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out"), "--plots"]) == 2
    err = capsys.readouterr().err
    assert 'pip install "kincal[plot]"' in err and err.count("\n") == 1 and os.listdir(tmp_path) == []


def test_calibrate_into_a_folder_with_other_files_adds_only_its_own(tmp_path, job):
    out = tmp_path / "out"
    _write(out, "notes.txt", "mine")
    assert main(["calibrate", str(job), "-o", str(out), "--quiet"]) in (0, 1)
    assert sorted(os.listdir(out)) == ["model.yaml", "notes.txt", "result.yaml"]
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_simulate_interrupted_leaves_nothing_and_overwrite_keeps_the_old(tmp_path, monkeypatch):
    """simulate checked only data.yaml: a half-written folder remained and the rerun was refused."""
    import kincal.io.datasets as datasets

    out = tmp_path / "sim"
    real = datasets.write_truth

    def interrupted(*a, **k):
        real(*a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(datasets, "write_truth", interrupted)
    argv = ["simulate", "ur10_tracker_markers", "-o", str(out), "--quiet"]
    assert main(argv) == 130 and os.listdir(tmp_path) == []
    monkeypatch.setattr(datasets, "write_truth", real)
    assert main(argv) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    monkeypatch.setattr(datasets, "write_truth", interrupted)
    assert main(argv + ["--overwrite", "--seed", "7"]) == 130
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert os.listdir(tmp_path) == ["sim"]


def test_demo_interrupted_while_its_simulation_moves_into_place_leaves_nothing(tmp_path, monkeypatch):
    _interrupt_during_the_move(monkeypatch)
    assert main(["demo", "-o", str(tmp_path / "demo"), "-n", "40", "--quiet"]) == 130
    assert os.listdir(tmp_path) == []


def test_demo_interrupted_during_the_calibration_leaves_nothing(tmp_path, monkeypatch):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate_cmds, "run_job", interrupted)
    assert main(["demo", "-o", str(tmp_path / "demo"), "-n", "40", "--quiet"]) == 130
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------------------------------ the kill test

PLOTS = ["identifiability.png", "prediction.png", "residuals.png", "uncertainty.png"]


def _start(job, out):
    code = "import sys; from kincal.cli import main; sys.exit(main())"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-c", code, "calibrate", str(job), "-o", str(out), "--plots",
                             "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)


def _undated(text: str) -> str:
    """result.yaml without the date its provenance records: the only line two runs of one job may differ in."""
    return "\n".join(line for line in text.splitlines() if not line.startswith("  date: "))


def _check_complete(out, reference):
    """A complete output: exactly the reference's entries, the same model and report, whole PNG files."""
    assert sorted(os.listdir(out)) == ["model.yaml", "plots", "result.yaml"]
    report = yaml.safe_load((out / "result.yaml").read_text())
    assert {"format", "version", "status", "estimates", "residuals_after", "validation"} <= set(report)
    assert report["format"] == "kincal-result" and len(report["estimates"]) > 0
    load_robot(str(out / "model.yaml"))
    assert (out / "model.yaml").read_bytes() == (reference / "model.yaml").read_bytes()
    assert _undated((out / "result.yaml").read_text()) == _undated((reference / "result.yaml").read_text())
    assert sorted(os.listdir(out / "plots")) == PLOTS
    for name in PLOTS:
        data = (out / "plots" / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[-8:] == b"IEND\xaeB`\x82"


@pytest.fixture(scope="module")
def reference(job, tmp_path_factory):
    """A complete run: its output to compare with, and its duration, over which the kill moments spread,
    measured as the kill runs go: two at a time."""
    folder = tmp_path_factory.mktemp("reference")
    t0 = time.perf_counter()
    runs = [_start(job, folder / name) for name in ("out", "twin")]
    for run in runs:
        assert run.wait() in (0, 1), run.stderr.read().decode()
    duration = time.perf_counter() - t0
    _check_complete(folder / "out", folder / "out")
    _check_complete(folder / "twin", folder / "out")  # deterministic: a complete output is this one
    return folder / "out", duration


def _kill_runs(job, reference, lanes, sig, delays):
    """Runs killed by ``sig`` after the ``delays``, two at a time, each lane writing to the same target ``out``
    (so a run meets what the killed one before it left). Returns how many outputs were absent and complete, and
    how many kills left a temporary (they hit the writing)."""
    killed_pids, outcomes = set(), {"absent": 0, "complete": 0, "stale": 0}
    for k in range(0, len(delays), 2):
        runs = []
        for lane, delay in zip(lanes, delays[k:k + 2]):
            lane.mkdir(parents=True, exist_ok=True)
            runs.append((lane, delay, _start(job, lane / "out"), time.perf_counter()))
        for lane, delay, proc, started in sorted(runs, key=lambda r: r[3] + r[1]):
            time.sleep(max(0.0, started + delay - time.perf_counter()))
            proc.send_signal(sig)
        for lane, delay, proc, _ in runs:
            rc = proc.wait()
            assert rc in (0, 1, 130, 143, -sig), (rc, proc.stderr.read().decode())
            killed_pids.add(proc.pid)
            out = lane / "out"
            if out.exists():
                _check_complete(out, reference)
                outcomes["complete"] += 1
                shutil.rmtree(out)
            else:
                outcomes["absent"] += 1
            for name in os.listdir(lane):  # only a recognisable temporary of a killed run may remain
                m = STALE.match(name)
                assert m and int(m.group(1)) in killed_pids and sig == signal.SIGKILL, name
                outcomes["stale"] += int(m.group(1)) == proc.pid
    return outcomes


def _kill_test(job, reference, tmp_path, count, seed, rerun, signals=(signal.SIGINT, signal.SIGKILL)):
    out, duration = reference
    rng = np.random.default_rng(seed)
    for sig in signals:
        lanes = [tmp_path / sig.name / "lane0", tmp_path / sig.name / "lane1"]
        outcomes = _kill_runs(job, out, lanes, sig, rng.uniform(0.0, duration, count))
        assert outcomes["absent"] + outcomes["complete"] == count
        lanes.sort(key=lambda lane: -len(os.listdir(lane)))  # the lane with most stale temporaries first
        for lane in lanes[:rerun]:  # a later run clears what killed runs left, and writes a complete output
            assert _start(job, lane / "out").wait() in (0, 1)
            assert os.listdir(lane) == ["out"]
            _check_complete(lane / "out", out)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_calibrate_killed_while_it_writes(job, reference, tmp_path, sig):
    """The moment that matters, hit for sure: the signal comes as soon as the temporary folder appears (the
    results and plots are being written). SIGINT leaves nothing; SIGKILL only the temporary, which the next
    run removes before it writes a complete output."""
    proc = _start(job, tmp_path / "out")
    deadline = time.perf_counter() + 10 * reference[1]
    while not any(STALE.match(n) for n in os.listdir(tmp_path)):
        assert proc.poll() is None and time.perf_counter() < deadline, "no temporary folder seen"
        time.sleep(0.002)
    proc.send_signal(sig)
    assert proc.wait() in (130, -sig)
    left = os.listdir(tmp_path)
    assert left == [] if sig == signal.SIGINT else (len(left) == 1 and STALE.match(left[0]))
    assert _start(job, tmp_path / "out").wait() in (0, 1)
    assert os.listdir(tmp_path) == ["out"]
    _check_complete(tmp_path / "out", reference[0])


def test_calibrate_killed_at_random_moments_leaves_nothing_or_everything(job, reference, tmp_path):
    """The short kill test: 2 SIGINTs and 2 SIGKILLs (the slow variant below does 20 of each, and SIGTERM)."""
    _kill_test(job, reference, tmp_path, 2, seed=10, rerun=0)


@pytest.mark.slow
def test_calibrate_killed_at_20_random_moments_per_signal(job, reference, tmp_path):
    _kill_test(job, reference, tmp_path, 20, seed=2026, rerun=1)
    _kill_test(job, reference, tmp_path / "term", 2, seed=7, rerun=0, signals=(signal.SIGTERM,))
