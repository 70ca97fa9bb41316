"""The thesis' own calibration algorithms (Bergström & Green 2016), reproduced as written, as baselines.

=========================  =========================================  =============  ==================
method                     thesis                                     data set kind  function
=========================  =========================================  =============  ==================
``single_offsets``         Algorithm 3, CalibSingle_offsets           ``clamp``      calib_single_offsets
``several_points``         Sec. 3.3, several fixed points (BFGS)      ``plate``      calib_several_points
``dual_offsets``           Algorithm 2, CalibDual_offsets             ``dual``       calib_dual_offsets
``dual_kinematic``         Algorithm 1, CalibDual_kinematic           ``dual``       calib_dual_kinematic
=========================  =========================================  =============  ==================

``eval_error`` is Algorithm 4 and ``estimate_clamp`` eq. 3.8. ``run(method, dataset, robot, **options)``
takes the arrays from a ``kincal.data.Dataset``; explicit keyword options override what the data set knows
(``T_world_fixture=None`` forgets a known fixture, ``T_toolA_toolB=None`` forces the eq. 3.8 estimate).
They are deliberately NOT fixed; see docs/thesis-baselines.md for what goes wrong and why.
"""

from __future__ import annotations

from kincal.baselines.thesis_common import BaselineResult, LoopSettings, eval_error, mean_transform
from kincal.baselines.thesis_dual import calib_dual_kinematic, calib_dual_offsets, estimate_clamp
from kincal.baselines.thesis_single import calib_several_points, calib_single_offsets
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError
from kincal.kinematics import Robot

METHODS = {
    "single_offsets": ("clamp", calib_single_offsets),
    "several_points": ("plate", calib_several_points),
    "dual_offsets": ("dual", calib_dual_offsets),
    "dual_kinematic": ("dual", calib_dual_kinematic),
}
_LOOP_OPTIONS = ("max_iter", "accept_factor", "damping", "step_tol")


def run(method: str, dataset: Dataset, robot: Robot, **options) -> BaselineResult:
    """Run one thesis baseline on a data set, starting from the (nominal) ``robot``.

    Options: ``max_iter``, ``accept_factor``, ``damping``, ``step_tol`` (least-squares loops), and the
    keyword arguments of the method's function (``known``, ``share``, ``original``, ``T_world_fixture``,
    ``T_toolA_toolB``, ...).
    """
    name = method.removeprefix("thesis.")
    if name not in METHODS:
        raise DegenerateExperimentError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    kind, fun = METHODS[name]
    if dataset.kind != kind:
        raise DegenerateExperimentError(
            f"data set '{dataset.name}': method '{name}' needs a '{kind}' data set, got '{dataset.kind}'"
        )
    loop = {k: options.pop(k) for k in _LOOP_OPTIONS if k in options}
    if loop and name == "several_points":
        raise DegenerateExperimentError(f"method 'several_points' uses BFGS; options {sorted(loop)} do not apply")
    if loop:
        options["settings"] = LoopSettings(**loop)
    arms = dataset.arms
    if kind == "clamp":
        options.setdefault("T_world_fixture", dataset.known.get("T_world_fixture"))
        return fun(robot[arms[0]], dataset.q[arms[0]], arm=arms[0], **options)
    if kind == "plate":
        return fun(
            robot[arms[0]], dataset.q[arms[0]], dataset.measured["fixture"], dataset.known["T_plate_fixture"],
            arm=arms[0], **options,
        )
    options.setdefault("T_toolA_toolB", dataset.known.get("T_toolA_toolB"))
    a, b = arms
    return fun(robot[a], robot[b], dataset.q[a], dataset.q[b], arms=(a, b), **options)


__all__ = [
    "BaselineResult",
    "LoopSettings",
    "METHODS",
    "calib_dual_kinematic",
    "calib_dual_offsets",
    "calib_several_points",
    "calib_single_offsets",
    "estimate_clamp",
    "eval_error",
    "mean_transform",
    "run",
]
