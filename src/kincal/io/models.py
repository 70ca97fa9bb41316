"""Model files: versioned YAML for arms and multi-arm robots (``format: kincal-model``, ``version: 1``).

The format is documented in docs/model-format.md. Files are read with ``yaml.safe_load`` and validated
field by field; every error is a DataFormatError naming the file and the field path
(``arms.left.joints[3].axis``), what was expected and what was found.

``load_robot`` accepts a file path or the name of a built-in robot (``builtin_names()``, the model files shipped
in ``kincal/io/builtin_robots``; ``kincal.robots`` is the user-facing catalogue over them).
``save_robot`` writes SI units (m, rad), joints as twists and poses as matrices, with shortest
round-trip float text, so ``load_robot(save_robot(x)) == x`` exactly.
"""

from __future__ import annotations

import math
import warnings
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from kincal.errors import DataFormatError, KincalError, KincalWarning, ModelError
from kincal.io import units
from kincal.lie.rotations import quat_wxyz_to_matrix, rpy_to_matrix
from kincal.io.yamlfile import clip, parse_yaml, quote, read_text
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel, Robot
from kincal.kinematics.lateral import lateral_axes
from kincal.lie import se3, so3

FORMAT = "kincal-model"
VERSION = 1
ROTATION_TOL = 1e-6  # published matrices are rounded; larger errors need `orthonormalize: true`
# `orthonormalize: true` projects rotations with max |R^T R - I| (quaternions and axes with |norm - 1|) up to this:
# rounding to 2 decimals and more; beyond it a matrix is a mistake, not a rounded rotation.
ORTHONORMALIZE_LIMIT = 1e-2
_BUILTIN = resources.files(__package__) / "builtin_robots"
BUILTIN_ROBOTS = _BUILTIN  # the folder of the built-in model files (a Traversable)
TWIST_TOL = 1e-9  # twists are what save_robot writes: they must already be exact joint screws
# A compliance below 0 is no joint's; a calibrated model keeps its estimates as fitted (docs/model-format.md).
NEGATIVE_HINT = ("; a calibrated model's estimates below 0 load with 'allow_negative_compliance: true' on the arm "
                 "(kincal writes it)")

_TOP_KEYS = {"format", "version", "name", "units", "meta", "arms", "orthonormalize"}
_ARM_KEYS = {"joints", "base", "home", "tool", "controller_order", "meta", "allow_negative_compliance",
             "mount", "couplings", "payload", "gravity"}
_JOINT_KEYS = {"name", "type", "axis", "point", "twist", "offset", "limits", "gear_ratio", "compliance", "mass", "com",
               "lateral", "lateral_axes"}
_POSE_KEYS = {"matrix", "xyz", "rpy", "quaternion_wxyz", "rotation", "orthonormalize"}


class _Ctx:
    """File name, unit factors and the current field path, for error messages."""

    def __init__(self, file: str, warn: bool = True):
        self.file = file
        self.length = 1.0
        self.angle = 1.0
        self.orthonormalize = False  # the file-level default of every pose's 'orthonormalize'
        self.warn = warn  # False for the built-in files: their projections are documented (docs/model-format.md)

    def fail(self, path: str, msg: str) -> DataFormatError:
        return DataFormatError(f"{self.file}: {path}: {msg}")

    def warning(self, path: str, msg: str) -> None:
        """A ``KincalWarning`` naming file and field: input accepted, but changed."""
        if self.warn:
            warnings.warn(f"{self.file}: {path}: {msg}", KincalWarning, stacklevel=2)

    def one_of(self, path: str, value: Any, allowed) -> str:
        """``value`` if it is one of the names ``allowed`` (text only: a list or mapping is never a name)."""
        if not isinstance(value, str) or value not in allowed:
            raise self.fail(path, f"expected one of {', '.join(allowed)}, found {quote(value)}")
        return value


# --------------------------------------------------------------------------------------------- reading


def load_robot(source) -> Robot:
    """A Robot from a model file path or a built-in robot name (see ``builtin_names()``)."""
    if isinstance(source, Robot):
        return source
    path = Path(source)
    if path.is_file():
        return read_robot(path)
    if str(source) in builtin_names():
        return load_builtin(str(source))
    raise DataFormatError(
        f"{source}: no such model file and no built-in robot of that name "
        f"(built-in robots: {', '.join(builtin_names())})"
    )


def builtin_names() -> list[str]:
    """Names of the built-in robots (the model files in ``kincal/io/builtin_robots``), sorted."""
    return sorted(f.name[: -len(".yaml")] for f in _BUILTIN.iterdir() if f.name.endswith(".yaml"))


def load_builtin(name: str) -> Robot:
    """The built-in robot ``name`` (e.g. ``"frida"``); DataFormatError lists the names if unknown."""
    if name not in builtin_names():
        raise DataFormatError(f"unknown built-in robot {quote(name)}; built-in robots: {', '.join(builtin_names())}")
    return parse_robot((_BUILTIN / f"{name}.yaml").read_text(encoding="utf-8"), f"{name}.yaml (built-in)",
                       warn=False)


def read_robot(path) -> Robot:
    """Read and validate one model file."""
    return parse_robot(read_text(path, "model file"), str(path))


def parse_robot(text: str, file: str = "<string>", *, warn: bool = True) -> Robot:
    """Validate the YAML text of a model file; ``file`` names it in error messages, and in the ``KincalWarning``s
    on what it changed (rounded rotations it projected) unless ``warn`` is false."""
    return robot_from_dict(parse_yaml(text, file), file, warn=warn)


def robot_from_dict(data: Any, file: str = "<dict>", *, warn: bool = True) -> Robot:
    """Validate a parsed model file (nested dicts and lists) and build the Robot."""
    ctx = _Ctx(file, warn)
    top = _mapping(ctx, data, "(top level)", _TOP_KEYS, required=("format", "version", "name", "units", "arms"))
    ctx.orthonormalize = _flag(ctx, top, "orthonormalize", "(top level)")
    if top["format"] != FORMAT:
        raise ctx.fail("format", f"expected {quote(FORMAT)}, found {quote(top['format'])}")
    if top["version"] != VERSION or isinstance(top["version"], bool):
        raise ctx.fail("version", f"expected {VERSION} (the only version this kincal reads), found "
                                  f"{quote(top['version'])}")
    name = _string(ctx, top["name"], "name")
    unit_map = _mapping(ctx, top["units"], "units", {"length", "angle"}, required=("length", "angle"))
    ctx.length = units.factor("length", unit_map["length"], f"{file}: units.length")
    ctx.angle = units.factor("angle", unit_map["angle"], f"{file}: units.angle")
    arms_data = top["arms"]
    if not isinstance(arms_data, dict) or not arms_data:
        raise ctx.fail("arms", f"expected a non-empty mapping of arm name -> arm, found {_kind(arms_data)}")
    arms = {}
    for arm_name, arm_data in arms_data.items():
        arm_name = _string(ctx, arm_name, f"arms.{arm_name}")
        arms[arm_name] = _arm(ctx, arm_name, arm_data, f"arms.{arm_name}")
    meta = _meta(ctx, top.get("meta", {}), "meta")
    mounts = _mounts(ctx, arms_data, arms)
    try:
        return Robot(name, arms, meta, mounts)
    except KincalError as exc:
        raise ctx.fail(f"arms.{_cycle_arm(exc, mounts)}.mount", str(exc)) from None


def _arm(ctx: _Ctx, name: str, data: Any, path: str) -> ArmModel:
    d = _mapping(ctx, data, path, _ARM_KEYS, required=("joints", "home"))
    joints = d["joints"]
    if not isinstance(joints, list) or not joints:
        raise ctx.fail(f"{path}.joints", f"expected a non-empty list of joints, found {_kind(joints)}")
    negative = _flag(ctx, d, "allow_negative_compliance", path)
    parsed = [_joint(ctx, j, f"{path}.joints[{i}]", i, negative) for i, j in enumerate(joints)]
    names = [p["name"] for p in parsed]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ctx.fail(f"{path}.joints[{i}].name", f"duplicate joint name {quote(n)}")
    order = None
    if "controller_order" in d:
        order = _controller_order(ctx, d["controller_order"], names, f"{path}.controller_order")
    poses = {key: _pose(ctx, d.get(key), f"{path}.{key}") for key in ("home", "base", "tool")}
    meta = _meta(ctx, d.get("meta", {}), f"{path}.meta")
    try:
        return ArmModel(
            name,
            np.array([p["twist"] for p in parsed]),
            poses["home"],
            base=poses["base"],
            tool=poses["tool"],
            offsets=[p["offset"] for p in parsed],
            lower=[p["lower"] for p in parsed],
            upper=[p["upper"] for p in parsed],
            gear_ratios=[p["gear_ratio"] for p in parsed],
            compliance=[0.0 if isinstance(p["compliance"], np.ndarray) else p["compliance"] for p in parsed],
            compliance_nodes={p["name"]: p["compliance"] for p in parsed if isinstance(p["compliance"], np.ndarray)},
            controller_order=order,
            joint_names=tuple(names),
            joint_types=tuple(p["type"] for p in parsed),
            meta=meta,
            allow_negative_compliance=negative,
            couplings=_couplings(ctx, d.get("couplings"), dict(zip(names, (p["type"] for p in parsed))),
                                 f"{path}.couplings"),
            **_mass_model(ctx, d, parsed, path),
            **_lateral_model(parsed),
        )
    except KincalError as exc:  # cross-field problems the per-field checks cannot see
        raise ctx.fail(path, str(exc)) from None


def _mounts(ctx: _Ctx, arms_data: dict, arms: dict) -> dict[str, str]:
    """``mount: <parent arm>`` of each arm (docs/model-format.md, "Tree-structured robots")."""
    out = {}
    for arm_name, arm_data in arms_data.items():
        if isinstance(arm_data, dict) and "mount" in arm_data:
            path = f"arms.{arm_name}.mount"
            parent = arm_data["mount"]
            if not isinstance(parent, str) or parent not in arms:
                raise ctx.fail(path, f"expected the name of another arm ({', '.join(arms)}), found {quote(parent)}")
            if parent == arm_name:
                raise ctx.fail(path, "an arm cannot be mounted on itself")
            out[arm_name] = parent
    return out


def _cycle_arm(exc: Exception, mounts: dict) -> str:
    """The arm a Robot's mount error names (``arm '<name>'``), for the field path of the message."""
    return next((a for a in mounts if f"arm '{a}'" in str(exc)), next(iter(mounts), "?"))


def _couplings(ctx: _Ctx, data: Any, types: dict[str, str], path: str) -> dict | None:
    """``couplings: {joint: {other joint: coefficient, constant: c}}``: coefficients are plain numbers, a
    constant is in the coupled joint's unit (the file's angle unit, or length unit for a prismatic joint)."""
    names = list(types)
    if data is None:
        return None
    if not isinstance(data, dict) or not data:
        raise ctx.fail(path, f"expected a mapping joint -> {{joint: coefficient}}, found {_kind(data)}")
    out = {}
    for joint, terms in data.items():
        at = _join(path, joint)
        if joint not in names:
            raise ctx.fail(at, f"expected a joint of this arm ({', '.join(names)}), found {quote(joint)}")
        if not isinstance(terms, dict) or not terms:
            raise ctx.fail(at, f"expected a mapping joint -> coefficient, found {_kind(terms)}")
        row = {}
        for other, coef in terms.items():
            where = _join(at, other)
            if other != "constant" and other not in names:
                raise ctx.fail(where, f"expected a joint of this arm ({', '.join(names)}) or 'constant', "
                                      f"found {quote(other)}")
            unit = (ctx.angle if types[joint] == REVOLUTE else ctx.length) if other == "constant" else 1.0
            row[other] = _number(ctx, coef, where) * unit
        out[joint] = row
    return out


def _joint(ctx: _Ctx, data: Any, path: str, index: int, negative: bool = False) -> dict:
    d = _mapping(ctx, data, path, _JOINT_KEYS)
    name = _string(ctx, d.get("name", f"j{index + 1}"), f"{path}.name")
    kind = d.get("type", REVOLUTE)
    if kind not in (REVOLUTE, PRISMATIC):
        raise ctx.fail(f"{path}.type", f"expected 'revolute' or 'prismatic', found {quote(kind)}")
    has_twist, has_axis = "twist" in d, "axis" in d
    if has_twist == has_axis:
        raise ctx.fail(path, "give the joint screw either as 'axis' (+ 'point' for revolute joints) or as 'twist', not "
                       + ("both" if has_twist else "neither"))
    if has_twist:
        if "point" in d:
            raise ctx.fail(f"{path}.point", "'point' goes with 'axis', not with 'twist'")
        twist = _twist(ctx, d["twist"], f"{path}.twist", kind)
    else:
        axis = _unit(ctx, _vector(ctx, d["axis"], f"{path}.axis", 3), f"{path}.axis", ctx.orthonormalize,
                     "a unit vector", "at the top of the file")
        axis = axis / np.linalg.norm(axis)
        if kind == REVOLUTE:
            if "point" not in d:
                raise ctx.fail(path, "missing key 'point' (a point on the axis of this revolute joint)")
            point = _vector(ctx, d["point"], f"{path}.point", 3) * ctx.length
            twist = se3.join(-np.cross(axis, point), axis)
        else:
            if "point" in d:
                raise ctx.fail(f"{path}.point", "a prismatic joint has a direction only; remove 'point'")
            twist = se3.join(axis, np.zeros(3))
    scale = ctx.angle if kind == REVOLUTE else ctx.length
    offset = _number(ctx, d.get("offset", 0.0), f"{path}.offset") * scale
    lower, upper = -math.inf, math.inf
    if "limits" in d:
        lim = d["limits"]
        if not isinstance(lim, list) or len(lim) != 2:
            raise ctx.fail(f"{path}.limits", f"expected [lower, upper], found {quote(lim)}")
        lower = -math.inf if lim[0] is None else _number(ctx, lim[0], f"{path}.limits[0]", finite=False) * scale
        upper = math.inf if lim[1] is None else _number(ctx, lim[1], f"{path}.limits[1]", finite=False) * scale
        if not lower < upper:
            raise ctx.fail(f"{path}.limits", f"expected lower < upper, found {quote(lim)}")
    ratio = _number(ctx, d.get("gear_ratio", 1.0), f"{path}.gear_ratio")
    if ratio == 0:
        raise ctx.fail(f"{path}.gear_ratio", "expected a non-zero gear ratio, found 0")
    if isinstance(d.get("compliance"), dict):
        compliance = _compliance_nodes(ctx, d["compliance"], f"{path}.compliance", kind, (lower, upper), negative)
    else:
        compliance = _number(ctx, d.get("compliance", 0.0), f"{path}.compliance") * scale
        if compliance < 0 and not negative:
            unit = "angle unit/(N m)" if kind == REVOLUTE else "length unit/N"
            raise ctx.fail(f"{path}.compliance", f"expected a compliance >= 0 ({unit}), found "
                           f"{quote(compliance / scale)}{NEGATIVE_HINT}")
    return {"name": name, "type": kind, "twist": twist, "offset": offset, "lower": lower, "upper": upper,
            "gear_ratio": ratio, "compliance": compliance, **_link_mass(ctx, d, path),
            **_joint_lateral(ctx, d, path, kind, negative)}


def _joint_lateral(ctx: _Ctx, d: dict, path: str, kind: str, negative: bool) -> dict:
    """A joint's ``lateral: [x, y]`` compliances (angle unit/(N m)) and optional ``lateral_axes`` (two twists,
    as ``save_robot`` writes them; default: ``kincal.kinematics.lateral.lateral_axes``)."""
    if "lateral" not in d:
        if "lateral_axes" in d:
            raise ctx.fail(f"{path}.lateral_axes", "'lateral_axes' goes with 'lateral' (the two compliances)")
        return {}
    if kind != REVOLUTE:
        raise ctx.fail(f"{path}.lateral", "lateral compliance (bending about the axes normal to the joint axis) "
                       "needs a revolute joint")
    c = _vector(ctx, d["lateral"], f"{path}.lateral", 2) * ctx.angle
    if np.any(c < 0) and not negative:
        raise ctx.fail(f"{path}.lateral", f"expected two lateral compliances >= 0 (angle unit/(N m)), found "
                       f"{quote(d['lateral'])}{NEGATIVE_HINT}")
    out = {"lateral": c}
    if "lateral_axes" in d:
        raw = d["lateral_axes"]
        if not isinstance(raw, list) or len(raw) != 2:
            raise ctx.fail(f"{path}.lateral_axes", f"expected two twists [x axis, y axis], found {quote(raw)}")
        out["lateral_axes"] = np.stack([_twist(ctx, t, f"{path}.lateral_axes[{i}]", REVOLUTE)
                                        for i, t in enumerate(raw)])
    return out


def _lateral_model(parsed: list[dict]) -> dict:
    """ArmModel's ``lateral`` and ``lateral_axes`` from the joints (none when no joint states ``lateral``; a
    joint without it then has zero lateral compliance)."""
    if not any("lateral" in p for p in parsed):
        return {}
    out = {"lateral": np.array([p.get("lateral", np.zeros(2)) for p in parsed])}
    if any("lateral_axes" in p for p in parsed):
        nominal = lateral_axes(np.array([p["twist"] for p in parsed]))
        out["lateral_axes"] = np.stack([p.get("lateral_axes", x) for p, x in zip(parsed, nominal)])
    return out


def _link_mass(ctx: _Ctx, d: dict, path: str) -> dict:
    """A joint's ``mass`` (kg) and ``com`` (length units, arm base frame at q = 0) of the link it moves."""
    if ("mass" in d) != ("com" in d):
        raise ctx.fail(path, "give a link's 'mass' (kg) and 'com' (its centre of mass) together")
    mass = _number(ctx, d.get("mass", 0.0), f"{path}.mass")
    if mass < 0:
        raise ctx.fail(f"{path}.mass", f"expected a mass >= 0 kg, found {quote(d['mass'])}")
    return {"mass": mass, "com": _vector(ctx, d.get("com", [0.0, 0.0, 0.0]), f"{path}.com", 3) * ctx.length}


def _mass_model(ctx: _Ctx, d: dict, joints: list[dict], path: str) -> dict:
    """ArmModel's mass fields: link masses from the joints, the arm's ``payload`` {mass, com (tool frame)} and
    ``gravity`` (m/s^2, world frame)."""
    out = {"link_masses": [j["mass"] for j in joints], "link_coms": [j["com"] for j in joints]}
    if "payload" in d:
        p = _mapping(ctx, d["payload"], f"{path}.payload", {"mass", "com"}, required=("mass", "com"))
        out.update(_link_mass(ctx, p, f"{path}.payload"))
        out["payload_mass"], out["payload_com"] = out.pop("mass"), out.pop("com")
    if "gravity" in d:
        out["gravity"] = _vector(ctx, d["gravity"], f"{path}.gravity", 3)
    return out


def _compliance_nodes(ctx: _Ctx, data: dict, path: str, kind: str, limits, negative: bool) -> np.ndarray:
    """``compliance: {nodes: [angles], values: [compliances]}`` -> (m, 2) rows (angle rad, rad/(N m))."""
    d = _mapping(ctx, data, path, {"nodes", "values"}, required=("nodes", "values"))
    if kind != REVOLUTE:
        raise ctx.fail(path, "compliance nodes (a compliance that depends on the joint angle) need a revolute joint; "
                       "give a prismatic joint one number")
    nodes, values = d["nodes"], d["values"]
    if not isinstance(nodes, list) or len(nodes) < 2:
        raise ctx.fail(f"{path}.nodes", f"expected a list of at least 2 joint angles, found {quote(nodes)}")
    if not isinstance(values, list) or len(values) != len(nodes):
        raise ctx.fail(f"{path}.values", f"expected {len(nodes)} compliances (one per node), found {quote(values)}")
    x = np.array([_number(ctx, v, f"{path}.nodes[{i}]") for i, v in enumerate(nodes)]) * ctx.angle
    c = np.array([_number(ctx, v, f"{path}.values[{i}]") for i, v in enumerate(values)]) * ctx.angle
    for i in range(1, len(x)):
        if x[i] <= x[i - 1]:
            raise ctx.fail(f"{path}.nodes[{i}]", f"expected node angles increasing strictly, found {quote(nodes[i])} "
                           f"after {quote(nodes[i - 1])}")
    for i, a in enumerate(x):
        if not limits[0] <= a <= limits[1]:
            raise ctx.fail(f"{path}.nodes[{i}]", f"expected a node within the joint limits "
                           f"[{limits[0] / ctx.angle:g}, {limits[1] / ctx.angle:g}], found {quote(nodes[i])}")
    for i, v in enumerate(c):
        if v < 0 and not negative:
            raise ctx.fail(f"{path}.values[{i}]", f"expected a compliance >= 0 (angle unit/(N m)), found "
                           f"{quote(values[i])}{NEGATIVE_HINT}")
    return np.stack([x, c], axis=-1)


def _twist(ctx: _Ctx, value: Any, path: str, kind: str) -> np.ndarray:
    xi = _vector(ctx, value, path, 6)
    v, w = se3.split(xi)
    if kind == PRISMATIC:
        if np.linalg.norm(w) > TWIST_TOL or abs(np.linalg.norm(v) - 1) > TWIST_TOL:
            raise ctx.fail(path, f"a prismatic twist needs w = 0 and a unit v (within {TWIST_TOL:g}); "
                           f"found |v| = {np.linalg.norm(v):.12g}, |w| = {np.linalg.norm(w):.3g}")
        return xi.copy()
    v = v * ctx.length
    if abs(np.linalg.norm(w) - 1) > TWIST_TOL or abs(w @ v) > TWIST_TOL:
        raise ctx.fail(path, f"a revolute twist needs a unit w and zero pitch w.v = 0 (within {TWIST_TOL:g}); "
                       f"found |w| = {np.linalg.norm(w):.12g}, w.v = {w @ v:.3g}; give 'axis' and 'point' instead")
    return se3.join(v, w)


def _pose(ctx: _Ctx, data: Any, path: str) -> np.ndarray:
    """A pose block -> 4x4 (SI). Omitted (None) means identity."""
    if data is None:
        return np.eye(4)
    d = _mapping(ctx, data, path, _POSE_KEYS)
    fix = _flag(ctx, d, "orthonormalize", path, ctx.orthonormalize)
    forms = [k for k in ("matrix", "rpy", "quaternion_wxyz", "rotation") if k in d]
    if len(forms) > 1:
        raise ctx.fail(path, f"give the rotation one way only; found {', '.join(forms)}")
    if "matrix" in d:
        if "xyz" in d:
            raise ctx.fail(f"{path}.xyz", "'matrix' already holds the translation; remove 'xyz'")
        M = _matrix(ctx, d["matrix"], f"{path}.matrix", 4, 4)
        if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-12:
            raise ctx.fail(f"{path}.matrix", f"last row must be [0, 0, 0, 1], found {M[3].tolist()}")
        return se3.make(_rotation(ctx, M[:3, :3], f"{path}.matrix", fix), M[:3, 3] * ctx.length)
    p = _vector(ctx, d.get("xyz", [0.0, 0.0, 0.0]), f"{path}.xyz", 3)
    rot_path = f"{path}.{forms[0]}" if forms else path
    if "rpy" in d:
        R = rpy_to_matrix(_vector(ctx, d["rpy"], rot_path, 3) * ctx.angle)
    elif "quaternion_wxyz" in d:
        R = quat_wxyz_to_matrix(_unit(ctx, _vector(ctx, d["quaternion_wxyz"], rot_path, 4), rot_path, fix,
                                      "a unit quaternion"))
    elif "rotation" in d:
        R = _rotation(ctx, _matrix(ctx, d["rotation"], rot_path, 3, 3), rot_path, fix)
    else:
        R = np.eye(3)
    return se3.make(R, p * ctx.length)


def _rotation(ctx: _Ctx, R: np.ndarray, path: str, fix: bool) -> np.ndarray:
    """A rotation matrix as given (orthonormal within ROTATION_TOL), or with ``fix`` its nearest rotation (SVD
    polar factor) when it is within ORTHONORMALIZE_LIMIT of one, with a warning saying how far its axes moved."""
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    found = f"max |R^T R - I| = {err:.3g}, det = {det:.6g}"
    if not fix:
        if err > ROTATION_TOL or abs(det - 1) > ROTATION_TOL:
            raise ctx.fail(path, f"rotation is not orthonormal: {found} (expected within {ROTATION_TOL:g}); set "
                           "'orthonormalize: true' to project a rounded published matrix onto the nearest rotation")
        return R
    if det <= 0:
        raise ctx.fail(path, f"cannot orthonormalize: determinant {det:.6g} is not positive")
    if err > ORTHONORMALIZE_LIMIT:
        raise ctx.fail(path, f"rotation is too far from orthonormal to be a rounded one: {found} (orthonormalize "
                       f"projects up to {ORTHONORMALIZE_LIMIT:g})")
    P = so3.project(R)
    if err > ROTATION_TOL:
        turned = round(float(np.degrees(_angles(R, P)).max()), 9)  # below 1e-9 deg: round-off, not a turn
        ctx.warning(path, f"rotation projected onto the nearest rotation ({found}): its axes turned by up to "
                          f"{turned:.3g} deg")
    return P


def _angles(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Angle (rad) between each column of A and of B (atan2 of |a x b| and a . b: exact also near 0)."""
    return np.arctan2(np.linalg.norm(np.cross(A.T, B.T), axis=-1), np.sum(A * B, axis=0))


def _unit(ctx: _Ctx, x: np.ndarray, path: str, fix: bool, what: str, where: str = "") -> np.ndarray:
    """``x`` of norm 1 within ROTATION_TOL, or with ``fix`` normalized when within ORTHONORMALIZE_LIMIT of it
    (a warning gives the norm found: the direction it stands for does not change)."""
    norm = float(np.linalg.norm(x))
    if abs(norm - 1) <= ROTATION_TOL:
        return x / norm if fix else x
    if not fix:
        raise ctx.fail(path, f"expected {what} (norm 1 within {ROTATION_TOL:g}), found norm {norm:.9g}; set "
                       f"'orthonormalize: true'{' ' + where if where else ''} to normalize a rounded one")
    if abs(norm - 1) > ORTHONORMALIZE_LIMIT:
        raise ctx.fail(path, f"expected {what}: norm {norm:.9g} is too far from 1 to be a rounded one "
                       f"(orthonormalize normalizes within {ORTHONORMALIZE_LIMIT:g})")
    ctx.warning(path, f"normalized to {what}: found norm {norm:.9g}")
    return x / norm


def _flag(ctx: _Ctx, d: dict, key: str, path: str, default: bool = False) -> bool:
    """The true/false value of ``key`` in mapping ``d`` (``default`` when absent)."""
    value = d.get(key, default)
    if not isinstance(value, bool):
        raise ctx.fail(_join(path, key), f"expected true or false, found {quote(value)}")
    return value


def _controller_order(ctx: _Ctx, value: Any, names: list[str], path: str) -> tuple[int, ...]:
    if not isinstance(value, list) or len(value) != len(names):
        raise ctx.fail(path, f"expected a list of the {len(names)} joint names in controller channel order, "
                       f"found {quote(value)}")
    order = []
    for i, n in enumerate(value):
        if n not in names:
            raise ctx.fail(f"{path}[{i}]", f"unknown joint {quote(n)}; joints: {', '.join(names)}")
        if names.index(n) in order:
            raise ctx.fail(f"{path}[{i}]", f"joint {quote(n)} appears twice")
        order.append(names.index(n))
    return tuple(order)


# ---------------------------------------------------------------------------------- small validators


def _kind(x: Any) -> str:
    if x is None:
        return "nothing"
    return type(x).__name__ if isinstance(x, (dict, list)) else f"{type(x).__name__} {quote(x)}"


def _mapping(ctx: _Ctx, data: Any, path: str, allowed: set, required: tuple = ()) -> dict:
    if not isinstance(data, dict):
        raise ctx.fail(path, f"expected a mapping, found {_kind(data)}")
    for key in data:
        if key not in allowed:
            raise ctx.fail(_join(path, key), f"unknown key {quote(key)}; allowed keys: {', '.join(sorted(allowed))}")
    for key in required:
        if key not in data:
            raise ctx.fail(path, f"missing key {quote(key)}")
    return data


def _join(path: str, key: Any) -> str:
    # a key that is not plain text (spaces, line breaks, a number) is shown quoted, so the message stays one line
    shown = clip(key) if isinstance(key, str) and key.isprintable() and key.strip() == key and key else quote(key)
    return shown if path == "(top level)" else f"{path}.{shown}"


def _string(ctx: _Ctx, x: Any, path: str) -> str:
    if not isinstance(x, str) or not x:
        raise ctx.fail(path, f"expected a non-empty string, found {_kind(x)}")
    return x


def _number(ctx: _Ctx, x: Any, path: str, finite: bool = True) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ctx.fail(path, f"expected a number, found {_kind(x)}")
    if finite and not math.isfinite(x):
        raise ctx.fail(path, f"expected a finite number, found {quote(x)}")
    if math.isnan(x):
        raise ctx.fail(path, "expected a number, found NaN")
    return float(x)


def _vector(ctx: _Ctx, x: Any, path: str, n: int) -> np.ndarray:
    if not isinstance(x, list) or len(x) != n:
        found = f"a list of length {len(x)}" if isinstance(x, list) else _kind(x)
        raise ctx.fail(path, f"expected a list of {n} numbers, found {found}")
    return np.array([_number(ctx, v, f"{path}[{i}]") for i, v in enumerate(x)])


def _matrix(ctx: _Ctx, x: Any, path: str, rows: int, cols: int) -> np.ndarray:
    if not isinstance(x, list) or len(x) != rows:
        found = f"{len(x)} rows" if isinstance(x, list) else _kind(x)
        raise ctx.fail(path, f"expected a {rows}x{cols} matrix as a list of {rows} rows, found {found}")
    return np.array([_vector(ctx, r, f"{path}[{i}]", cols) for i, r in enumerate(x)])


def _meta(ctx: _Ctx, x: Any, path: str) -> dict:
    if x is None:  # an empty `meta:` line
        return {}
    if not isinstance(x, dict):
        raise ctx.fail(path, f"expected a mapping, found {_kind(x)}")
    return x


# --------------------------------------------------------------------------------------------- writing


def robot_to_dict(robot: Robot) -> dict:
    """The model-file content of a Robot in SI units: joints as twists, poses as matrices."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "name": robot.name,
        "units": {"length": "m", "angle": "rad"},
        **({"meta": _plain(robot.meta)} if robot.meta else {}),
        "arms": {key: {**({"mount": robot.mounts[key]} if key in robot.mounts else {}), **_arm_to_dict(arm)}
                 for key, arm in robot.arms.items()},
    }


def _arm_to_dict(arm: ArmModel) -> dict:
    joints = []
    for i, name in enumerate(arm.joint_names):
        j = {"name": name, "type": arm.joint_types[i], "twist": _floats(arm.screws[i])}
        if arm.offsets[i] != 0:
            j["offset"] = float(arm.offsets[i])
        if np.isfinite(arm.lower[i]) or np.isfinite(arm.upper[i]):
            j["limits"] = [float(arm.lower[i]), float(arm.upper[i])]
        if arm.gear_ratios[i] != 1:
            j["gear_ratio"] = float(arm.gear_ratios[i])
        if name in arm.compliance_nodes:
            t = arm.compliance_nodes[name]
            j["compliance"] = {"nodes": _floats(t[:, 0]), "values": _floats(t[:, 1])}
        elif arm.compliance[i] != 0:
            j["compliance"] = float(arm.compliance[i])
        if arm.link_masses[i] != 0 or np.any(arm.link_coms[i]):
            j.update(mass=float(arm.link_masses[i]), com=_floats(arm.link_coms[i]))
        if arm.lateral is not None:  # the axes too: calibrated twists carry them, they are no longer nominal
            j.update(lateral=_floats(arm.lateral[i]), lateral_axes=[_floats(x) for x in arm.lateral_axes[i]])
        joints.append(j)
    out = {
        "base": {"matrix": [_floats(r) for r in arm.base]},
        "home": {"matrix": [_floats(r) for r in arm.home]},
        "tool": {"matrix": [_floats(r) for r in arm.tool]},
    }
    if arm.allow_negative_compliance:
        out["allow_negative_compliance"] = True
    if arm.controller_order != tuple(range(arm.dof)):
        out["controller_order"] = [arm.joint_names[i] for i in arm.controller_order]
    if arm.meta:
        out["meta"] = _plain(arm.meta)
    if arm.couplings:
        out["couplings"] = {j: dict(t) for j, t in arm.couplings.items()}
    out.update(_mass_to_dict(arm))
    out["joints"] = joints
    return out


def _mass_to_dict(arm: ArmModel) -> dict:
    """The arm's ``payload`` and ``gravity`` keys, when set (link masses are joint keys)."""
    out = {}
    if arm.payload_mass != 0 or np.any(arm.payload_com):
        out["payload"] = {"mass": float(arm.payload_mass), "com": _floats(arm.payload_com)}
    if arm.gravity is not None:
        out["gravity"] = _floats(arm.gravity)
    return out


def _floats(a) -> list[float]:
    return [float(x) + 0.0 for x in a]  # + 0.0 turns -0.0 into 0.0


def _plain(x: Any) -> Any:
    """Mappings/sequences/numpy scalars -> plain YAML-safe Python values."""
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def dump_robot(robot: Robot) -> str:
    """Model-file text for a Robot (see ``robot_to_dict``)."""
    header = "# kincal model file (docs/model-format.md); written by kincal.io.save_robot\n"
    return header + yaml.safe_dump(robot_to_dict(robot), sort_keys=False, default_flow_style=None, width=120)


def save_robot(robot: Robot, path, *, overwrite: bool = False) -> Path:
    """Write ``robot`` as a model file; refuses to replace an existing file unless ``overwrite=True``."""
    path = Path(path)
    text = dump_robot(robot)
    try:
        with open(path, "w" if overwrite else "x", encoding="utf-8") as fh:
            fh.write(text)
    except FileExistsError:
        raise DataFormatError(f"{path}: file exists; not overwritten (pass overwrite=True to replace it)") from None
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot write model file: {exc.strerror or exc}") from None
    return path


def select_arm(robot: Robot, arm: str | None = None) -> ArmModel:
    """The named arm, or the only arm when ``arm`` is None; ModelError names the available arms."""
    if arm is None:
        if len(robot.arms) == 1:
            return next(iter(robot.arms.values()))
        raise ModelError(f"robot '{robot.name}' has several arms ({', '.join(robot.arms)}); choose one")
    return robot[arm]
