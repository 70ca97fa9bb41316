"""Job files: parsing to SI, clear errors naming file and field, running a job."""

import numpy as np
import pytest
import yaml

from kincal.errors import DataFormatError
from kincal.io.datasets import write_dataset
from kincal.io.jobs import load_job
from kincal.robots import load
from kincal.simulate.generators import generate_clamp
from kincal.simulate.perturb import perturb_robot
from kincal.workflow import run_job


@pytest.fixture(scope="module")
def clamp_dir(tmp_path_factory):
    frida = load("frida")
    true = perturb_robot(frida, "thesis", 3)
    ds, _, _ = generate_clamp(true.replace_arm("right", frida["right"].replace(offsets=true["right"].offsets)),
                              "right", n=20, rng=4, known_fixture=True)
    d = tmp_path_factory.mktemp("job")
    write_dataset(ds, d / "clamp.yaml", frida, model="frida")
    return d


def _job(d, **fields):
    top = {"format": "kincal-job", "version": 1, "model": "frida", "data": [{"manifest": "clamp.yaml"}], **fields}
    p = d / f"job{len(list(d.glob('job*.yaml')))}.yaml"
    p.write_text(yaml.safe_dump(top))
    return p


def test_job_parses_units_and_runs(clamp_dir):
    p = _job(clamp_dir, free="offsets", priors={"right.j1.offset": {"sigma_deg": 1.0, "mean_deg": 0.5}},
             data=[{"manifest": "clamp.yaml", "noise": {"joint_deg": 0.001, "position_mm": 0.02}}],
             solver={"loss": "linear", "max_outer": 5})
    job = load_job(p)
    assert job.priors["right.j1.offset"].sigma == pytest.approx(np.pi / 180)
    assert job.priors["right.j1.offset"].mean == pytest.approx(0.5 * np.pi / 180)
    nz = job.noise[job.datasets[0].name]
    assert nz.joint == pytest.approx(0.001 * np.pi / 180) and nz.position == pytest.approx(2e-5)
    res = run_job(job)
    assert res.status == "converged" and res.identifiability.deficiency == 0


@pytest.mark.parametrize("fields,message", [
    ({"free": "everything"}, "field 'free' is 'everything'"),
    ({"colour": 1}, r"unknown field\(s\) \['colour'\]"),
    ({"solver": {"method": "magic"}}, "solver.method is 'magic'"),
    ({"solver": {"loss": "l3"}}, "solver.loss is 'l3'"),
    ({"priors": {"right.j1.offset": {"sigma_deg": -1}}}, "sigma must be positive"),
    ({"data": [{"manifest": "clamp.yaml", "noise": {"joint_furlong": 1}}]}, "unknown angle unit 'furlong'"),
    ({"data": []}, "field 'data' must be a non-empty list"),
])
def test_job_errors_name_file_and_field(clamp_dir, fields, message):
    p = _job(clamp_dir, **fields)
    with pytest.raises(DataFormatError, match=message) as err:
        load_job(p)
    assert str(p) in str(err.value)
