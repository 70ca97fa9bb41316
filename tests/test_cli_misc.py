"""``kincal robots``, ``kincal scenarios``, the top-level help, and BLAS threads limited inside the CLI
(issue #12, items 2 and 6)."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info

from kincal.cli import SHORT_HELP, blas_threads, cli, main
from kincal.io.datasets import BUILTIN_SCENARIOS
from kincal.io.models import builtin_names


def test_robots_and_scenarios_one_line_each(capsys):
    assert main(["robots"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [ln.split()[0] for ln in lines] == builtin_names()
    assert any("ur10" in ln and "6 joints" in ln for ln in lines)
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert sorted(ln.split()[0] for ln in lines) == sorted(p.stem for p in BUILTIN_SCENARIOS.glob("*.yaml"))
    clamp = next(ln for ln in lines if ln.startswith("frida_clamp_one"))
    assert clamp.endswith('"One fixed point").')  # a whole sentence, not cut at "Sec."


def test_every_command_has_a_whole_short_help(capsys):
    assert set(cli.commands) == set(SHORT_HELP)
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    commands = out[out.index("Commands:"):]
    assert "..." not in commands
    for text in SHORT_HELP.values():
        assert text in commands


def _blas_threads():
    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


@pytest.mark.skipif(not _blas_threads(), reason="no BLAS library reports its threads")
def test_blas_threads_limited_inside_the_cli_unless_the_user_chose(monkeypatch):
    for v in ("KINCAL_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(v, raising=False)
    with blas_threads():
        assert _blas_threads() == {1}
    monkeypatch.setenv("KINCAL_BLAS_THREADS", "2")
    with blas_threads():
        assert _blas_threads() == {2}
    monkeypatch.delenv("KINCAL_BLAS_THREADS")
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    before = _blas_threads()
    with blas_threads():  # the user's choice stands
        assert _blas_threads() == before
