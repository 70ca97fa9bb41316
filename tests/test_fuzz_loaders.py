"""Hostile input, fuzzed (issue #10): every loader, fed mutated versions of valid files, either loads or raises
one of kincal's own errors with a one-line message. Anything else (a Python traceback) fails the test.

Mutations act on the structure (a value replaced by one of another type, a key dropped or added), on the text
(characters inserted, deleted or replaced, lines repeated) and on the bytes (encodings). ``FUZZ_EXAMPLES``
examples per loader run in the suite; the ``slow`` variant runs 2000 per loader and is part of CI's run.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kincal import robots
from kincal.errors import KincalError
from kincal.io.datasets import load_dataset, load_scenario, scenario_path, write_dataset
from kincal.io.jobs import load_job
from kincal.io.logs import convert_log
from kincal.io.models import dump_robot, load_robot, parse_robot
from kincal.simulate import generate_markers

FUZZ_EXAMPLES = int(os.environ.get("KINCAL_FUZZ_EXAMPLES", "150"))
SLOW_EXAMPLES = 2000

# Empty lists and mappings are built fresh: one shared object (st.just({})) could be added into itself.
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12), st.just(".inf"), st.builds(list), st.builds(dict),
                    st.lists(st.floats(-1e3, 1e3), max_size=5), st.dictionaries(st.text(max_size=5), st.integers(),
                                                                                max_size=3))


def _paths(value, prefix=()):
    """Every path to a value inside nested dicts and lists."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, prefix + (i,))


def _set(tree, path, value):
    if not path:
        return value
    node = tree
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return tree


@st.composite
def mutated_yaml(draw, base: dict):
    """YAML text of ``base`` with a structural mutation, then maybe a textual one."""
    tree = yaml.safe_load(yaml.safe_dump(base))
    paths = list(_paths(tree))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "drop", "add"]))
        parent = tree
        try:
            for p in path[:-1]:
                parent = parent[p]
        except (KeyError, IndexError, TypeError):
            continue
        if action == "replace":
            tree = _set(tree, path, draw(scalars))
        elif action == "drop" and path and isinstance(parent, (dict, list)):
            try:
                del parent[path[-1]]
            except (KeyError, IndexError, TypeError):
                pass
        elif action == "add" and isinstance(parent, dict):
            parent[draw(st.one_of(st.text(max_size=8), st.integers()))] = draw(scalars)
        paths = list(_paths(tree))
    text = yaml.safe_dump(tree, allow_unicode=True)
    return draw(mutated_text(text))


@st.composite
def mutated_text(draw, text: str):
    """The text with a few characters inserted, deleted or replaced, or a line repeated (or unchanged)."""
    for _ in range(draw(st.integers(0, 2))):
        if not text:
            break
        i = draw(st.integers(0, len(text) - 1))
        op = draw(st.sampled_from(["insert", "delete", "replace", "line"]))
        ch = draw(st.sampled_from(list("0123456789.-e,:#[]{}*&!'\"\n\t x\ufeff\u00e9")))
        if op == "insert":
            text = text[:i] + ch + text[i:]
        elif op == "delete":
            text = text[:i] + text[i + 1:]
        elif op == "replace":
            text = text[:i] + ch + text[i + 1:]
        else:
            lines = text.splitlines(keepends=True)
            k = draw(st.integers(0, len(lines) - 1))
            text = "".join(lines[:k + 1] + lines[k:])
    return text


def _encoded(text: str, how: str) -> bytes:
    return {"utf-8": text.encode("utf-8"), "bom": b"\xef\xbb\xbf" + text.encode("utf-8"),
            "utf-16": text.encode("utf-16"), "latin-1": text.encode("latin-1", "replace")}[how]


def _only_kincal_errors(load):
    """Run ``load``; pass if it returns or raises a one-line KincalError."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy overflow warnings are not the question here
        try:
            load()
        except KincalError as exc:
            assert "\n" not in str(exc), f"multi-line error: {exc}"


# ----------------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A valid model text, a markers data set (manifest + CSV), a job over it, and a motor log."""
    d = tmp_path_factory.mktemp("valid")
    ur = robots.load("ur10")
    ds, _, _ = generate_markers(ur, None, n=6, rng=0)
    manifest = write_dataset(ds, d / "data.yaml", ur, model="ur10", length="mm", angle="deg")
    job = {"format": "kincal-job", "version": 1, "name": "j", "model": "ur10",
           "data": [{"manifest": "data.yaml", "noise": {"position_mm": 0.02}}], "free": ["offsets"],
           "priors": {"arm.*.offset": {"sigma_deg": 1.0}}, "solver": {"max_outer": 5, "rank_rtol": 1e-9}}
    log_lines = ["t," + ",".join(f"arm.c{i + 1}" for i in range(6))]
    log_lines += [f"{0.004 * k}," + ",".join(f"{0.01 * k * (i + 1)}" for i in range(6)) for k in range(20)]
    return {"dir": d, "model": dump_robot(ur), "manifest": yaml.safe_load(manifest.read_text()),
            "csv": manifest.with_suffix(".csv").read_text(), "job": job, "log": "\n".join(log_lines) + "\n",
            "scenario": yaml.safe_load(scenario_path("ur10_tracker_markers").read_text())}


def _write(d: Path, name: str, data: bytes) -> Path:
    p = d / name
    p.write_bytes(data)
    return p


# ------------------------------------------------------------------------------------------------- tests


def _model_case(files, data):
    text = data.draw(mutated_yaml(yaml.safe_load(files["model"])))
    how = data.draw(st.sampled_from(["utf-8", "bom", "utf-16", "latin-1"]))
    _only_kincal_errors(lambda: parse_robot(text, "m.yaml"))
    p = _write(files["dir"], "m_fuzz.yaml", _encoded(text, how))
    _only_kincal_errors(lambda: load_robot(p))


def _manifest_case(files, data):
    d = files["dir"]
    text = data.draw(mutated_yaml(files["manifest"]))
    csv_text = data.draw(mutated_text(files["csv"]))
    _write(d, files["manifest"]["data"], csv_text.encode("utf-8"))
    p = _write(d, "fuzz.yaml", _encoded(text, data.draw(st.sampled_from(["utf-8", "bom", "utf-16"]))))
    _only_kincal_errors(lambda: load_dataset(p))
    _write(d, files["manifest"]["data"], files["csv"].encode("utf-8"))


def _job_case(files, data):
    text = data.draw(mutated_yaml(files["job"]))
    p = _write(files["dir"], "job_fuzz.yaml", text.encode("utf-8"))
    _only_kincal_errors(lambda: load_job(p))


def _log_case(files, data):
    text = data.draw(mutated_text(files["log"]))
    p = _write(files["dir"], "log_fuzz.csv", _encoded(text, data.draw(st.sampled_from(["utf-8", "bom", "latin-1"]))))
    still = data.draw(st.one_of(st.none(), st.floats(allow_nan=True), st.just(1e-3)))
    per_stop = data.draw(st.booleans())
    _only_kincal_errors(lambda: convert_log(p, robots.load("ur10"), ("arm",), still_rad_s=still, per_stop=per_stop))


def _scenario_case(files, data):
    text = data.draw(mutated_yaml(files["scenario"]))
    p = _write(files["dir"], "scenario_fuzz.yaml", text.encode("utf-8"))
    _only_kincal_errors(lambda: load_scenario(p))


CASES = {"model": _model_case, "manifest": _manifest_case, "job": _job_case, "log": _log_case,
         "scenario": _scenario_case}
SETTINGS = dict(deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


def _fuzz(files, loader: str, examples: int) -> None:
    @settings(max_examples=examples, **SETTINGS)
    @given(st.data())
    def run(data):
        CASES[loader](files, data)

    run()


@pytest.mark.parametrize("loader", sorted(CASES))
def test_loaders_raise_only_kincal_errors(files, loader):
    _fuzz(files, loader, FUZZ_EXAMPLES)


@pytest.mark.slow
@pytest.mark.parametrize("loader", sorted(CASES))
def test_loaders_raise_only_kincal_errors_2000(files, loader):
    _fuzz(files, loader, SLOW_EXAMPLES)


def test_the_fuzz_reaches_the_loaders(files):
    """The valid inputs load (so mutations start from something a loader accepts)."""
    parse_robot(files["model"], "m.yaml")
    p = _write(files["dir"], "valid_job.yaml", yaml.safe_dump(files["job"]).encode())
    assert load_job(p).name == "j"
    t, q = convert_log(_write(files["dir"], "valid_log.csv", files["log"].encode()), robots.load("ur10"), ("arm",))
    assert len(t) == 20 and np.all(np.isfinite(q["arm"]))
