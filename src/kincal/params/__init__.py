"""Calibration parameters: kinds, values, named local coordinates, free/fixed/prior status, retraction.

What the solver moves are *local coordinates* around a linearization state. Each block of coordinates has a
parameter kind (``kincal.params.kinds``) that owns its names, units, retraction, displacement, scale and
re-centring:

==================  ==========================================  =============================================
kind                local coordinates (stable names)            retraction
==================  ==========================================  =============================================
``OFFSETS``         ``right.j3.offset``                         ``o + d``
``TWISTS``          ``right.j3.xi.shift_1, shift_2, tilt_1,     ``Ad(exp(G d)) xi``: a rigid motion of the
                    tilt_2`` (prismatic: ``tilt_1, tilt_2``)    joint axis (stays unit, zero pitch)
``HOME/BASE/TOOL``  ``right.home.v_x .. w_z``                   ``exp(d) T`` (left increment)
``COMPLIANCE``      ``right.j3.compliance`` (rad/Nm; m/N)       ``c + d`` (meaningful only with loads)
``LATERAL``         ``right.j3.lateral_x, lateral_y`` (rad/Nm)  ``l + d``: bending about the joint's lateral
                                                                axes (arms that declare it; level ``lateral``)
``POSE``            ``fixture.v_x .. w_z``                      ``exp(d) T``
``POINT/POINTS``    ``socket.x``, ``markers.m1.x``              ``p + d``
``PLANE``           ``plane.n_1, plane.n_2, plane.d``           ``n = normalize(n0 + U d_n)``, ``d + d_d``
==================  ==========================================  =============================================

Twists: reports and priors use the chart ``B^+ (xi - xi0)``; tangent bases are re-linearized between outer
iterations (``recentre``). A new kind is a ``ParamKind`` subclass in kinds.py; nothing else changes.
"""

from kincal.params.kinds import (
    ARM_KINDS,
    BASE,
    COMPLIANCE,
    COMPLIANCE_UNITS,
    FRAME_KINDS,
    HOME,
    LATERAL,
    OFFSETS,
    PLANE,
    POINT,
    POINTS,
    POSE,
    POSE_COORDS,
    TOOL,
    TWISTS,
    ParamKind,
)
from kincal.params.layout import LEVELS, Block, Layout, Prior, build_layout, clear_caches, level_patterns
from kincal.params.ops import (
    conform,
    displacement,
    pose_retraction_jacobians,
    recentre,
    retract,
    scale_direction,
    twist_coordinates,
)
from kincal.params.values import ArmValues, Plane, State

__all__ = [
    "ARM_KINDS", "ArmValues", "BASE", "Block", "COMPLIANCE", "COMPLIANCE_UNITS", "FRAME_KINDS", "HOME", "LATERAL", "LEVELS",
    "Layout", "OFFSETS", "PLANE", "POINT", "POINTS", "POSE", "POSE_COORDS", "ParamKind", "Plane", "Prior", "State",
    "TOOL", "TWISTS", "build_layout", "clear_caches", "conform", "displacement", "level_patterns",
    "pose_retraction_jacobians", "recentre", "retract", "scale_direction", "twist_coordinates",
]
