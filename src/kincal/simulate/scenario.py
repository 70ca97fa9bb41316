"""A simulation scenario: nominal robot, how the true robot differs, one experiment, noise, validation size.

Scenario files (YAML, ``format: kincal-scenario``) are read and checked by ``kincal.io.datasets.load_scenario``
into plain data (a mapping, SI units); ``build_scenario`` makes a ``Scenario`` of it and ``run`` turns that into
``(true robot, Dataset, Truth, validation)``. Examples ship in ``kincal/scenarios/*.yaml`` and the format is
documented in docs/simulation.md.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from kincal.data import Dataset
from kincal.kinematics import Robot
from kincal.simulate.generators import GENERATORS
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import Perturbation, perturb_robot, perturbation, with_errors


@dataclass(frozen=True, eq=False)
class Scenario:
    """A parsed scenario (SI units).

    ``options`` are the keyword arguments of the generator of ``kind`` (``GENERATORS[kind]``), e.g.
    ``arm``, ``n``, ``known_fixture``, ``clamp``, ``workspace``.
    """

    name: str
    robot: Robot
    model: str
    kind: str
    options: Mapping
    perturbation: Perturbation
    perturb_arms: tuple[str, ...] | None = None
    noise: Noise = field(default_factory=Noise)
    n_validation: int = 100
    seed: int = 0
    angle_unit: str = "rad"
    length_unit: str = "m"
    errors: Mapping[str, float] = field(default_factory=dict)  # explicit errors of the true robot (SI), if any


def build_scenario(spec: Mapping[str, Any]) -> Scenario:
    """A ``Scenario`` from the plain data of ``load_scenario``: ``name``, ``robot``, ``model``, ``kind``,
    ``options`` (the generator's keyword arguments, SI), ``truth`` (``level``, ``overrides`` {field: SI value},
    ``arms``; or ``errors`` {parameter name: SI value}), ``noise``, ``validation``, ``seed``, ``output`` ({angle, length} unit names)."""
    truth = spec["truth"]
    arms = truth.get("arms")
    return Scenario(
        name=spec["name"], robot=spec["robot"], model=spec["model"], kind=spec["kind"], options=dict(spec["options"]),
        perturbation=perturbation(truth.get("level", "thesis"), **truth.get("overrides", {})),
        perturb_arms=tuple(arms) if arms else None, noise=spec.get("noise", Noise()),
        n_validation=spec.get("validation", 100), seed=spec.get("seed", 0),
        angle_unit=spec.get("output", {}).get("angle", "rad"), length_unit=spec.get("output", {}).get("length", "m"),
        errors=dict(truth.get("errors") or {}),
    )


def run(scenario: Scenario, progress: Callable[[int, int], None] | None = None):
    """Simulate: returns ``(true_robot, dataset, truth, validation)``; the same seed gives the same output.

    The seed drives two independent streams: one for the true robot, one for the experiment.
    """
    robot_rng, data_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(scenario.seed).spawn(2))
    true = (with_errors(scenario.robot, scenario.errors) if scenario.errors else
            perturb_robot(scenario.robot, scenario.perturbation, robot_rng, arms=scenario.perturb_arms))
    gen = GENERATORS[scenario.kind]
    options = dict(scenario.options)
    if "progress" in inspect.signature(gen).parameters:  # generators walking a self-motion report progress
        options["progress"] = progress
    ds, truth, validation = gen(true, rng=data_rng, noise=scenario.noise, n_validation=scenario.n_validation, **options)
    # name the data set after the scenario and point it at the nominal model it belongs to
    def rename(d, name):
        return Dataset(d.kind, scenario.model, d.arms, d.q, d.measured, d.known, name, d.meta)

    ds = rename(ds, scenario.name)
    validation = {a: rename(v, f"{scenario.name}-validation-{a}") for a, v in validation.items()}
    return true, ds, truth, validation
