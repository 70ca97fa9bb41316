"""One noise concept: typed quantities, the same spelling in Python and files, no guessed weights."""

import numpy as np
import pytest

from kincal import robots
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import Problem, calibrate
from kincal.estimation.problem import stated_sigmas
from kincal.io.units import noise_from_file
from kincal.noise import DEFAULT, PIXEL, POSITION, Noise
from kincal.simulate import generate_pose


def test_noise_file_spelling_matches_python():
    n = noise_from_file({"position_mm": 0.02, "orientation_deg": 0.01, "joint_deg": 0.001, "pixel_px": 0.5}, "f: noise")
    assert n.position == pytest.approx(2e-5) and n.joint == pytest.approx(np.deg2rad(0.001))
    assert n.sigma(PIXEL) == 0.5 and n.sigma(POSITION) == n.position
    assert Noise.from_si(n.as_si()) == n


@pytest.mark.parametrize("bad, match", [({"position_furlong": 1}, "unknown length unit"),
                                        ({"speed_mm": 1}, "speed_mm: unknown key"),
                                        ({"joint_deg": -1}, "expected a finite number >= 0"),
                                        ({"pixel_mm": 1}, "unknown pixel unit")])
def test_noise_file_errors_name_the_field(bad, match):
    with pytest.raises(DataFormatError, match=match):
        noise_from_file(bad, "job.yaml: data[0].noise")


def test_noise_over_and_validation():
    assert Noise(position=1.0).over(DEFAULT) == Noise(position=1.0, orientation=1e-5, joint=1e-5)
    with pytest.raises(ModelError, match="expected a finite number"):
        Noise(joint=float("nan"))


def test_unstated_quantity_is_an_error_not_a_guess():
    ur = robots.load("ur10")
    ds, _, _ = generate_pose(ur, None, n=20, rng=0)
    # whitening never guesses: a noise without an orientation sigma cannot whiten orientation residuals ...
    exp = Problem.build(ur, [ds], "offsets").experiments[0]
    with pytest.raises(ModelError, match="orientation residuals .* no orientation standard deviation"):
        stated_sigmas(exp, Noise(position=1e-5))
    # ... and the one noise rule states it: the argument over the data set's own over kincal.noise.DEFAULT
    assert Problem.build(ur, [ds], "offsets", noise=Noise(position=1e-5)).noise[0].orientation == DEFAULT.orientation
    assert calibrate(ur, [ds], "offsets", noise=Noise(position=1e-5, orientation=1e-5)).status == "converged"
