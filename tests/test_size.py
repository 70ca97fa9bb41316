"""Size (issue #10): a 200,000-row data set either calibrates within the memory the solve's estimate promised
(``kincal.estimation.memory``), measured as the peak resident size of a separate process, or is refused up
front, before anything the size of the data is allocated, with the estimate and the limit in one line."""

import json
import resource
import subprocess
import sys
import textwrap
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from kincal.cli import main
from kincal.errors import ResourceError
from kincal.estimation.memory import ENV, PER_CELL, PER_ROW, memory_limit, solve_bytes
from kincal.io.datasets import write_dataset
from kincal.io.jobs import write_job
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import Perturbation, perturb_robot

ROWS = 200_000


@pytest.fixture(scope="module")
def big_job(tmp_path_factory):
    """A markers data set of ROWS configurations (one marker, known on the tool: 3 residual rows each): 2000
    simulated ones repeated, each copy with a little more noise (far below the stated noise)."""
    folder = tmp_path_factory.mktemp("big")
    ur10 = load("ur10")
    true = perturb_robot(ur10, Perturbation(offset_rad=0.002), rng=1)  # what "offsets" (the job's default) can fit
    ds, _, _ = generate_markers(true, n=2000, rng=3, markers=1, known_markers=True,
                                noise=Noise(position=2e-5))
    rng = np.random.default_rng(0)
    reps = ROWS // ds.size
    p = ds.measured["p_tracker_marker"]
    ds = replace(ds, q={"arm": np.tile(ds.q["arm"], (reps, 1))},
                 measured={"p_tracker_marker": np.concatenate([p + rng.normal(0, 1e-7, p.shape) for _ in range(reps)])})
    manifest = write_dataset(ds, folder / "data.yaml", ur10, model="ur10")
    return write_job(folder / "job.yaml", name="big", model="ur10", data=[manifest.name])


def test_a_solve_that_will_not_fit_is_refused_before_it_starts(big_job, monkeypatch, capsys):
    monkeypatch.setenv(ENV, "100M")
    out = big_job.parent / "refused"
    tracemalloc.start()
    try:
        code = main(["calibrate", str(big_job), "-o", str(out), "--quiet"])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and line.startswith("kincal: error: the solve needs about")
    assert f"{3 * ROWS} residual rows x 0 free parameters" in line and f"but {ENV} is 100 MiB" in line
    assert not out.exists()
    # refused before anything of the solve's size was allocated: the loaded data and little more
    assert peak < solve_bytes(3 * ROWS, 0) / 10


_RUN = textwrap.dedent("""
    import json, os, resource, sys
    from kincal.estimation.memory import residual_rows, solve_bytes
    from kincal.io.jobs import load_job
    from kincal.workflow import run_job
    job = load_job(sys.argv[1])
    held = int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")  # resident before the solve
    res = run_job(job)
    rows, free = residual_rows(job.datasets), len(res.problem.free_idx)
    print(json.dumps({"status": res.status, "rows": rows, "free": free, "estimate": solve_bytes(rows, free),
                      "held": held, "maxrss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
""")


@pytest.mark.slow
def test_a_solve_that_fits_stays_within_its_estimate(big_job):
    run = subprocess.run([sys.executable, "-c", _RUN, str(big_job)], capture_output=True, text=True, timeout=900,
                         env={"OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["status"] == "converged" and got["rows"] == 3 * ROWS, got
    assert got["estimate"] == solve_bytes(got["rows"], got["free"])
    # the process' peak beyond what it held before the solve (interpreter, libraries, the loaded data)
    assert got["maxrss"] - got["held"] <= got["estimate"], got
    assert resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 <= got["held"] + got["estimate"]


def test_the_limit_is_the_available_memory_unless_overridden(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    limit, source = memory_limit()
    assert 0 < limit and ("available RAM" in source or "cgroup" in source)
    for text, expected in (("1500", 1500), ("64M", 64 * 2**20), ("2.5G", int(2.5 * 2**30)), ("8GiB", 8 * 2**30)):
        monkeypatch.setenv(ENV, text)
        assert memory_limit() == (expected, ENV)
    monkeypatch.setenv(ENV, "lots")
    with pytest.raises(ResourceError, match=rf"{ENV}='lots': expected a number of bytes"):
        memory_limit()
    assert solve_bytes(1000, 10) == 8 * 1000 * (PER_ROW + 10 * PER_CELL)
