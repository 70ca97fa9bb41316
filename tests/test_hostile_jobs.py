"""Job files with wrong types (issue #10): each gets a one-line error naming the file and the field."""

import pytest
import yaml

from kincal import robots
from kincal.errors import DataFormatError
from kincal.io.datasets import write_dataset
from kincal.io.jobs import load_job
from kincal.simulate import generate_clamp

BASE = {"format": "kincal-job", "version": 1, "model": "frida", "data": [{"manifest": "clamp.yaml"}],
        "free": "offsets"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("jobs")
    frida = robots.load("frida")
    ds, _, _ = generate_clamp(frida, "right", n=10, rng=0, explore_options={"n_seeds": 4, "n_steps": 30})
    write_dataset(ds, d / "clamp.yaml", frida, model="frida")
    return d


@pytest.mark.parametrize("change, match", [
    ({"priors": ["a", "b"]}, r"field priors: expected a mapping or nothing, found \['a', 'b'\]"),
    ({"priors": {"arm.*.offset": {1: 2}}}, r"field priors\.arm\.\*\.offset: expected text keys, found the key 1"),
    ({"data": [{"manifest": "clamp.yaml", "noise": 0.02}]}, r"field data\[0\]\.noise: expected a mapping or nothing"),
    ({"data": [{"manifest": "clamp.yaml", "noise": [1, 2]}]}, r"field data\[0\]\.noise: expected a mapping"),
    ({"constraints": [{1: "x"}]}, r"field constraints\[0\]: expected text keys, found the key 1"),
    ({1: "x", "colour": 2}, r"field \(top level\): expected text keys, found the key 1"),
    ({"solver": {"max_outer": float("inf")}}, r"field solver\.max_outer: expected a finite number, found inf"),
    ({"solver": {"max_outer": 2.5}}, r"field solver\.max_outer: expected an integer, found 2\.5"),
    ({"solver": {"f_scale": True}}, r"field solver\.f_scale: expected a number, found True"),
    ({"solver": {"correlation_threshold": 5}}, r"field solver\.correlation_threshold: expected a number <= 1"),
    ({"version": True}, r"field version: expected an integer, found True"),
    ({"gauge": []}, r"field gauge: expected at least 1 item\(s\), found \[\]"),
])
def test_wrong_types_name_file_and_field(folder, change, match):
    job = folder / "job.yaml"
    job.write_text(yaml.safe_dump({**BASE, **change}))
    with pytest.raises(DataFormatError, match=r"job\.yaml: " + match) as e:
        load_job(job)
    assert "\n" not in str(e.value)


def test_exponent_floats_in_a_job_are_numbers(folder):
    job = folder / "job.yaml"
    job.write_text(yaml.safe_dump(BASE) + "solver: {rank_rtol: 1e-7}\n")
    assert load_job(job).options["rank_rtol"] == 1e-7
