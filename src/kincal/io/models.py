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
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from kincal.errors import DataFormatError, KincalError, ModelError
from kincal.io import units
from kincal.lie.rotations import quat_wxyz_to_matrix, rpy_to_matrix
from kincal.io.yamlfile import clip, parse_yaml, quote, read_text
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel, Robot
from kincal.lie import se3, so3

FORMAT = "kincal-model"
VERSION = 1
ROTATION_TOL = 1e-6  # published matrices are rounded; larger errors need `orthonormalize: true`
AXIS_TOL = 1e-6
_BUILTIN = resources.files(__package__) / "builtin_robots"
BUILTIN_ROBOTS = _BUILTIN  # the folder of the built-in model files (a Traversable)
TWIST_TOL = 1e-9  # twists are what save_robot writes: they must already be exact joint screws

_TOP_KEYS = {"format", "version", "name", "units", "meta", "arms"}
_ARM_KEYS = {"joints", "base", "home", "tool", "controller_order", "meta", "payload", "gravity"}
_JOINT_KEYS = {"name", "type", "axis", "point", "twist", "offset", "limits", "gear_ratio", "compliance", "mass", "com"}
_POSE_KEYS = {"matrix", "xyz", "rpy", "quaternion_wxyz", "rotation", "orthonormalize"}


class _Ctx:
    """File name, unit factors and the current field path, for error messages."""

    def __init__(self, file: str):
        self.file = file
        self.length = 1.0
        self.angle = 1.0

    def fail(self, path: str, msg: str) -> DataFormatError:
        return DataFormatError(f"{self.file}: {path}: {msg}")

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
    return parse_robot((_BUILTIN / f"{name}.yaml").read_text(encoding="utf-8"), f"{name}.yaml (built-in)")


def read_robot(path) -> Robot:
    """Read and validate one model file."""
    return parse_robot(read_text(path, "model file"), str(path))


def parse_robot(text: str, file: str = "<string>") -> Robot:
    """Validate the YAML text of a model file; ``file`` names it in error messages."""
    return robot_from_dict(parse_yaml(text, file), file)


def robot_from_dict(data: Any, file: str = "<dict>") -> Robot:
    """Validate a parsed model file (nested dicts and lists) and build the Robot."""
    ctx = _Ctx(file)
    top = _mapping(ctx, data, "(top level)", _TOP_KEYS, required=("format", "version", "name", "units", "arms"))
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
    return Robot(name, arms, meta)


def _arm(ctx: _Ctx, name: str, data: Any, path: str) -> ArmModel:
    d = _mapping(ctx, data, path, _ARM_KEYS, required=("joints", "home"))
    joints = d["joints"]
    if not isinstance(joints, list) or not joints:
        raise ctx.fail(f"{path}.joints", f"expected a non-empty list of joints, found {_kind(joints)}")
    parsed = [_joint(ctx, j, f"{path}.joints[{i}]", i) for i, j in enumerate(joints)]
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
            **_mass_model(ctx, d, parsed, path),
        )
    except KincalError as exc:  # cross-field problems the per-field checks cannot see
        raise ctx.fail(path, str(exc)) from None


def _joint(ctx: _Ctx, data: Any, path: str, index: int) -> dict:
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
        axis = _vector(ctx, d["axis"], f"{path}.axis", 3)
        norm = float(np.linalg.norm(axis))
        if abs(norm - 1.0) > AXIS_TOL:
            raise ctx.fail(f"{path}.axis",
                           f"expected a unit vector (norm 1 within {AXIS_TOL:g}), found norm {norm:.9g}")
        axis = axis / norm
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
        compliance = _compliance_nodes(ctx, d["compliance"], f"{path}.compliance", kind, (lower, upper))
    else:
        compliance = _number(ctx, d.get("compliance", 0.0), f"{path}.compliance") * scale
        if compliance < 0:
            unit = "angle unit/(N m)" if kind == REVOLUTE else "length unit/N"
            raise ctx.fail(f"{path}.compliance", f"expected a compliance >= 0 ({unit}), found {quote(compliance / scale)}")
    return {"name": name, "type": kind, "twist": twist, "offset": offset, "lower": lower, "upper": upper,
            "gear_ratio": ratio, "compliance": compliance, **_link_mass(ctx, d, path)}


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


def _compliance_nodes(ctx: _Ctx, data: dict, path: str, kind: str, limits) -> np.ndarray:
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
        if v < 0:
            raise ctx.fail(f"{path}.values[{i}]", f"expected a compliance >= 0 (angle unit/(N m)), found {quote(values[i])}")
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
    fix = d.get("orthonormalize", False)
    if not isinstance(fix, bool):
        raise ctx.fail(f"{path}.orthonormalize", f"expected true or false, found {quote(fix)}")
    forms = [k for k in ("matrix", "rpy", "quaternion_wxyz", "rotation") if k in d]
    if len(forms) > 1:
        raise ctx.fail(path, f"give the rotation one way only; found {', '.join(forms)}")
    if "matrix" in d:
        if "xyz" in d:
            raise ctx.fail(f"{path}.xyz", "'matrix' already holds the translation; remove 'xyz'")
        M = _matrix(ctx, d["matrix"], f"{path}.matrix", 4, 4)
        if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-12:
            raise ctx.fail(f"{path}.matrix", f"last row must be [0, 0, 0, 1], found {M[3].tolist()}")
        R, p = M[:3, :3], M[:3, 3]
        rot_path = f"{path}.matrix"
    else:
        p = _vector(ctx, d.get("xyz", [0.0, 0.0, 0.0]), f"{path}.xyz", 3)
        rot_path = f"{path}.{forms[0]}" if forms else path
        if "rpy" in d:
            R = rpy_to_matrix(_vector(ctx, d["rpy"], rot_path, 3) * ctx.angle)
        elif "quaternion_wxyz" in d:
            q = _vector(ctx, d["quaternion_wxyz"], rot_path, 4)
            norm = float(np.linalg.norm(q))
            if fix and norm > 0:
                q = q / norm
            elif abs(norm - 1) > ROTATION_TOL:
                raise ctx.fail(rot_path, f"expected a unit quaternion (norm 1 within {ROTATION_TOL:g}), found norm "
                               f"{norm:.9g}; set 'orthonormalize: true' to normalize it")
            R = quat_wxyz_to_matrix(q)
        elif "rotation" in d:
            R = _matrix(ctx, d["rotation"], rot_path, 3, 3)
        else:
            R = np.eye(3)
    if fix:
        if np.linalg.det(R) <= 0:
            raise ctx.fail(rot_path, f"cannot orthonormalize: determinant {np.linalg.det(R):.6g} is not positive")
        R = so3.project(R)
    else:
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        det = float(np.linalg.det(R))
        if err > ROTATION_TOL or abs(det - 1) > ROTATION_TOL:
            raise ctx.fail(rot_path, f"rotation is not orthonormal: max |R^T R - I| = {err:.3g}, det = {det:.6g} "
                           f"(expected within {ROTATION_TOL:g}); set 'orthonormalize: true' to project a rounded "
                           "published matrix onto the nearest rotation")
    return se3.make(R, p * ctx.length)


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
        "arms": {key: _arm_to_dict(arm) for key, arm in robot.arms.items()},
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
        joints.append(j)
    out = {
        "base": {"matrix": [_floats(r) for r in arm.base]},
        "home": {"matrix": [_floats(r) for r in arm.home]},
        "tool": {"matrix": [_floats(r) for r in arm.tool]},
    }
    if arm.controller_order != tuple(range(arm.dof)):
        out["controller_order"] = [arm.joint_names[i] for i in arm.controller_order]
    if arm.meta:
        out["meta"] = _plain(arm.meta)
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
