"""Fewer redundant equations than identifiable parameters: calibrated, with the stated noise as the floor of the
standard deviations, and trusted only once validated (``Result.low_redundancy``)."""

from dataclasses import replace

import numpy as np
import pytest
from rich.console import Console

from kincal.cli.calibrate_cmds import print_summary
from kincal.errors import DegenerateExperimentError
from kincal.estimation import Noise, calibrate
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise as SimNoise, tracker_points
from kincal.simulate.perturb import perturb_robot

UR10 = load("ur10")
SIGMA = 5e-5


def _noisy(n: int, seed: int):
    true = perturb_robot(UR10, "fine", 3)
    ds, _, val = generate_markers(true, n=n, rng=100 + seed, markers=1)
    rng = np.random.default_rng(seed)
    noisy = replace(ds, measured={"p_tracker_marker": tracker_points(ds.measured["p_tracker_marker"],
                                                                     SimNoise(position=SIGMA), rng)})
    return noisy, val[ds.arms[0]]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ten_markers_calibrate_with_low_redundancy(seed):
    """One marker, 10 configurations: 30 equations for 45 free coordinates of which 27 are identifiable."""
    ds, val = _noisy(10, seed)
    res = calibrate(UR10, [ds], "kinematic", noise=Noise(position=SIGMA))
    assert res.status == "converged" and res.identifiability.rank == 27 and len(res.linearization.r) == 30
    assert res.low_redundancy and not res.trusted and not res.success
    assert any(m.startswith("low redundancy: 30 equations for 27") for m in res.messages)
    assert res.scale == max(res.sigma2, 1.0)
    # the covariance is the unscaled one times the scale: never smaller than the stated noise gives
    unit = res.covariance / res.scale
    ok = np.array([e.identifiable for e in res.estimates])
    std = np.array([e.std for e in res.estimates])
    assert np.allclose(std[ok], np.sqrt(np.diag(unit))[ok] * np.sqrt(max(res.sigma2, 1.0)), rtol=1e-9)
    validated = calibrate(UR10, [ds], "kinematic", noise=Noise(position=SIGMA), validation=[val])
    assert validated.low_redundancy and validated.trusted
    assert validated.validation[0].after.position_rms < validated.validation[0].before.position_rms / 5
    console = Console(record=True, width=200)
    print_summary(console, res, "job")
    assert "NOT TRUSTED: low redundancy and no validation data" in console.export_text()


def test_enough_redundancy_is_not_low():
    ds, _ = _noisy(30, 0)
    res = calibrate(UR10, [ds], "kinematic", noise=Noise(position=SIGMA))
    assert not res.low_redundancy and res.trusted and res.scale == res.sigma2
    assert not any("low redundancy" in m for m in res.messages)


def test_equations_that_limit_the_rank_are_refused():
    """9 configurations: 27 equations cannot show that only 27 of the 45 coordinates are identifiable."""
    ds, _ = _noisy(9, 0)
    with pytest.raises(DegenerateExperimentError, match=r"27 equations for 45 unknowns \(27 found identifiable"):
        calibrate(UR10, [ds], "kinematic", noise=Noise(position=SIGMA))
