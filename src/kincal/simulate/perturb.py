"""True robots: a nominal model with random kinematic errors (thesis Sec. 3.4 "Parameter identification").

Every error is drawn uniformly in ``[-a, a]`` per coordinate:

- joint twists: ``xi_i + (dv, dw)`` with ``|dv_j| <= twist_m`` and ``|dw_j| <= twist_rad``, then re-conformed
  with ``conform_twists`` (unit axis, zero pitch) as the thesis does;
- joint offsets: ``|o_i| <= offset_rad`` (``offset_m`` for prismatic joints), added to the nominal offsets;
- home (T_st), base and tool: additive in twist coordinates, ``exp(log(T) + (dv, dw))``.

Joint compliances (``compliance``, rad/(N m) for revolute and m/N for prismatic joints) are drawn uniformly in
``[0, compliance]``, last and only when set, so the other draws (and robots of earlier seeds) are unchanged.

Named levels: ``"thesis"`` (0.01 m, 2.4 deg, 0.07 rad offsets, home perturbed like the twists) and
``"fine"`` (1 mm, 0.1 deg, 0.01 rad). Base and tool stay nominal unless their magnitudes are set.

``with_errors``: explicit errors instead, by parameter name (a scenario's or study's ``truth.errors``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from kincal.errors import ModelError
from kincal.kinematics import PRISMATIC, ArmModel, Robot, conform_twists
from kincal.lie import se3
from kincal.params import State, build_layout, retract

_DEG = np.pi / 180


@dataclass(frozen=True)
class Perturbation:
    """Half-widths of the uniform errors (SI). Zero leaves a part nominal."""

    twist_m: float = 0.0
    twist_rad: float = 0.0
    offset_rad: float = 0.0
    offset_m: float = 0.0
    home_m: float = 0.0
    home_rad: float = 0.0
    base_m: float = 0.0
    base_rad: float = 0.0
    tool_m: float = 0.0
    tool_rad: float = 0.0
    compliance: float = 0.0

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if not (np.isfinite(v) and v >= 0):
                raise ModelError(f"perturbation {k}: expected a finite magnitude >= 0, got {v!r}")


LEVELS = {
    "none": Perturbation(),
    "thesis": Perturbation(0.01, 2.4 * _DEG, 0.07, 0.001, 0.01, 2.4 * _DEG),
    "fine": Perturbation(0.001, 0.1 * _DEG, 0.01, 0.0001, 0.001, 0.1 * _DEG),
}


def perturbation(level: str | Perturbation | None = "thesis", **overrides: float) -> Perturbation:
    """A named level (``"thesis"``, ``"fine"``, ``"none"``) or explicit magnitudes, with fields overridden."""
    if isinstance(level, Perturbation):
        base = level
    elif level is None:
        base = LEVELS["none"]
    else:
        try:
            base = LEVELS[level]
        except KeyError:
            raise ModelError(f"perturbation level {level!r}: expected one of {', '.join(LEVELS)}") from None
    try:
        return replace(base, **overrides)
    except TypeError as exc:
        raise ModelError(f"perturbation: {exc}; fields: {', '.join(Perturbation.__dataclass_fields__)}") from None


def _twist_noise(rng, shape, a_m, a_rad):
    return se3.join(rng.uniform(-1, 1, shape + (3,)) * a_m, rng.uniform(-1, 1, shape + (3,)) * a_rad)


def _perturb_pose(T, rng, a_m, a_rad):
    if a_m == 0 and a_rad == 0:
        return np.array(T)
    return se3.exp(se3.log(T) + _twist_noise(rng, (), a_m, a_rad))


def perturb_arm(model: ArmModel, p: Perturbation, rng: np.random.Generator) -> ArmModel:
    """One arm with errors of magnitudes ``p``; draws in a fixed order (twists, offsets, home, base, tool, then
    compliance only if ``p.compliance`` > 0)."""
    n = model.dof
    screws = conform_twists(model.screws + _twist_noise(rng, (n,), p.twist_m, p.twist_rad), model.joint_types)
    prismatic = np.array([t == PRISMATIC for t in model.joint_types])
    offsets = model.offsets + rng.uniform(-1, 1, n) * np.where(prismatic, p.offset_m, p.offset_rad)
    return model.replace(
        screws=screws,
        offsets=offsets,
        home=_perturb_pose(model.home, rng, p.home_m, p.home_rad),
        base=_perturb_pose(model.base, rng, p.base_m, p.base_rad),
        tool=_perturb_pose(model.tool, rng, p.tool_m, p.tool_rad),
        meta={**model.meta, "perturbed_from": model.name},
        compliance=rng.uniform(0, p.compliance, n) if p.compliance > 0 else model.compliance,
    )


def perturb_robot(
    robot: Robot,
    level: str | Perturbation | None = "thesis",
    rng: np.random.Generator | int | None = None,
    *,
    arms: tuple[str, ...] | None = None,
    **overrides: float,
) -> Robot:
    """A "true" robot: the nominal ``robot`` with random kinematic errors.

    Parameters
    ----------
    robot : Robot (or a single ArmModel, returned perturbed as an ArmModel).
    level : "thesis", "fine", "none" or a ``Perturbation``; ``overrides`` replace single magnitudes
        (e.g. ``base_m=0.002``).
    rng : numpy Generator or seed; the same seed gives the same robot.
    arms : arms to perturb (default all, in the robot's order); the others stay nominal.
    """
    p = perturbation(level, **overrides)
    rng = np.random.default_rng(rng)
    if isinstance(robot, ArmModel):
        return perturb_arm(robot, p, rng)
    chosen = tuple(robot.arms) if arms is None else tuple(arms)
    for a in chosen:
        robot[a]
    new = {a: perturb_arm(m, p, rng) if a in chosen else m for a, m in robot.arms.items()}
    return Robot(robot.name, new, {**robot.meta, "perturbation": str(level)}, robot.mounts)


def with_errors(robot: Robot, errors) -> Robot:
    """``robot`` moved by explicit ``errors`` {parameter name: SI value} (the names ``kincal calibrate`` reports;
    each a displacement of that coordinate from the nominal value, as calibration reports changes)."""
    state = State.from_robot(robot)
    layout = build_layout(state, list(errors))
    d = np.zeros(layout.size)
    for name, value in errors.items():
        d[layout.index(name)] = value
    return retract(state, layout, d).to_robot(robot)
