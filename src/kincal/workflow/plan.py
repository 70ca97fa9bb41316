"""Plan jobs: the data entries that name a scenario or a configurations file (read by ``kincal.io.planjobs``)
turned into data sets of the **nominal** robot's readings, so that ``kincal analyze`` and ``kincal design`` run
on a job before anything is measured (docs/job-format.md, "Planning without measured data").

A scenario's configurations are drawn by its generator with its seed, with its stated noise (``kincal analyze
SCENARIO`` reads a scenario the same way); a configurations file's are taken as given, noise-free, stating no
noise (the entry's ``noise:`` or kincal's default applies, as for any data set). Each data set is marked
``meta["planned"]``, so that calibrating it is refused (``kincal.workflow.jobs``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from kincal.data import Dataset
from kincal.errors import DataFormatError
from kincal.io import jobs
from kincal.io.planjobs import PREDICTABLE, Plan
from kincal.kinematics import Robot
from kincal.kinematics.tree import tip_pose
from kincal.lie import se3
from kincal.schema import SCHEMAS
from kincal.simulate import GENERATORS, Noise
from kincal.simulate.perturb import perturbation
from kincal.simulate.scenario import build_scenario, run


def load_plan_job(path, confine: bool = False) -> jobs.Job:
    """``kincal.io.jobs.load_job``, with planned data entries made data sets (module docstring)."""
    return jobs.load_job(path, confine, plan=planned_dataset)


def planned_dataset(plan: Plan, robot: Robot) -> Dataset:
    """The nominal robot's readings of a planned entry."""
    ds = scenario_dataset(plan.scenario, robot)[1] if plan.scenario is not None else _configurations(plan, robot)
    # marked, so that calibrate refuses it: the nominal robot's own readings fit the nominal model exactly
    return replace(ds, meta={**ds.meta, "planned": plan.label})


def scenario_dataset(spec: Mapping, robot: Robot | None = None) -> tuple[Robot, Dataset]:
    """(robot, data set) of a scenario read by ``load_scenario``, simulated on the nominal ``robot`` (default:
    the scenario's own): its configurations and stated noise, its ``truth:`` ignored."""
    sc = build_scenario(spec)
    sc = replace(sc, robot=robot or sc.robot, perturbation=perturbation("none"))
    return sc.robot, run(sc)[1]


def _configurations(plan: Plan, robot: Robot) -> Dataset:
    """The configurations file's rows measured by the nominal robot; the experiment's generator (one draw)
    gives its arms, known frames and nominal frame values."""
    ds, truth, _ = GENERATORS[plan.kind](robot, n=1, rng=0, noise=Noise(), n_validation=1, **plan.options)
    table = plan.table
    arms = list(dict.fromkeys(c for a in ds.arms for c in robot.lineage(a)))  # a mounted arm's carriers too
    q = {a: table.take([f"{a}.{j}" for j in robot[a].joint_names]) * plan.angle for a in arms}
    extra = [c for c in table.header if c not in table.used]
    if extra:
        raise DataFormatError(f"{table.path}: line {table.header_line}, column '{extra[0]}': not a joint of the "
                              f"experiment's arms; expected the columns "
                              f"{', '.join(f'{a}.{j}' for a in arms for j in robot[a].joint_names)}")
    measured = {k: _NOMINAL[k](robot, ds.arms, q, truth.values) for k in PREDICTABLE
                if any(m.key == k for m in SCHEMAS[plan.kind].measured)}
    return Dataset(plan.kind, robot.name, ds.arms, q, measured, dict(ds.known), plan.name, {})


def _tool_in_tracker(robot: Robot, arms, q, values) -> np.ndarray:
    (arm,) = arms
    return se3.inverse(values["T_world_tracker"]) @ tip_pose(robot, arm, q)  # through a mounted arm's carriers


def _markers_in_tracker(robot: Robot, arms, q, values) -> np.ndarray:
    return se3.transform_points(_tool_in_tracker(robot, arms, q, values)[:, None], values["p_tool_marker"][None])


# The nominal robot's measurement, per entry kincal can predict from configurations alone (io's PREDICTABLE).
_NOMINAL = {"T_tracker_tool": _tool_in_tracker, "p_tracker_marker": _markers_in_tracker}
assert set(_NOMINAL) == set(PREDICTABLE)
