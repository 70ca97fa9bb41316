"""The layering in pyproject.toml ([tool.importlinter]) holds, and the check really catches an upward import."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).parent / "lint-imports"
LAYERS = "kincal layers: dependencies point down"


def _lint(cwd: Path, src: Path) -> subprocess.CompletedProcess:
    """lint-imports with the contracts of ``cwd/pyproject.toml`` on the kincal package found in ``src``."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    return subprocess.run([str(LINT), "--no-logo", "--no-cache", "--config", str(cwd / "pyproject.toml")],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def lint_available():
    if not LINT.exists():
        pytest.fail(f"{LINT} is missing: install the test extra (pip install -e '.[test]')")


def test_the_source_tree_keeps_every_contract(lint_available):
    run = _lint(ROOT, ROOT / "src")
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"{LAYERS} KEPT" in run.stdout
    assert "only kincal.report imports matplotlib KEPT" in run.stdout
    assert "only kincal.io imports yourdfpy (io.urdf) KEPT" in run.stdout
    assert "0 broken" in run.stdout


def test_an_upward_import_breaks_the_layers_contract(lint_available, tmp_path):
    shutil.copytree(ROOT / "src" / "kincal", tmp_path / "src" / "kincal",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    so3 = tmp_path / "src" / "kincal" / "lie" / "so3.py"
    so3.write_text(so3.read_text() + "\nimport kincal.cli  # deliberately wrong: the bottom imports the top\n")
    run = _lint(tmp_path, tmp_path / "src")
    assert run.returncode != 0
    assert f"{LAYERS} BROKEN" in run.stdout
    assert "kincal.lie.so3 -> kincal.cli" in run.stdout, run.stdout
    # the copy, not the installed tree, was analysed: the original still passes
    assert "kincal.lie.so3 -> kincal.cli" not in _lint(ROOT, ROOT / "src").stdout


def test_no_function_over_60_lines_in_the_core():
    """estimation/, analysis/ and params stay made of short functions (issue #8)."""
    import ast

    src = Path(__file__).resolve().parents[1] / "src" / "kincal"
    long = []
    for folder in ("estimation", "analysis", "params"):
        files = sorted((src / folder).rglob("*.py"))
        assert files, folder
        for path in files:
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    if node.end_lineno - node.lineno + 1 > 60:
                        long.append(f"{path.relative_to(src)}:{node.name}")
    assert long == []
