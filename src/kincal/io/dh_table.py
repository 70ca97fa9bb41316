"""DH table files (``format: kincal-dh``): what ``kincal export --to dh|mdh`` writes and ``kincal import`` reads
(docs/deploy.md, "DH table files").

```yaml
format: kincal-dh
convention: standard            # or modified (Craig)
arm: arm                        # optional (default arm)
joints:                         # base to flange, one row per joint
  - {joint: j1, type: revolute, a_m: 0, alpha_rad: 1.5708, d_m: 0.1273, theta_rad: 0, limits: [-6.28, 6.28]}
  - {joint: j2, a_mm: -612, alpha_deg: 0, d_mm: 0, theta_deg: 0}     # each value in m or mm, rad or deg
base: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]       # optional 4x4 (m): T_world_DH0
flange: {xyz: [0, 0, 0.1], rpy: [0, 0, 0]}                          # optional (m, rad): T_DHn_flange
tool: ...                                                           # optional: T_flange_tool
```

``T_world_tool(q) = base @ A_1(q_1) ... A_n(q_n) @ flange @ tool`` (``kincal.kinematics.dh``). A row's
``limits`` (optional, ``null`` for no bound) are in its theta unit (revolute) or d unit (prismatic). Other
keys the export writes (``formula``, ``chain``, ``check``) are read as comments. Errors name the file, the row
and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kincal.errors import ModelError
from kincal.io.models import _Ctx, _mapping, _number, _pose, _string
from kincal.io.yamlfile import parse_yaml, quote, read_text
from kincal.kinematics import ArmModel, Robot, forward_kinematics
from kincal.kinematics.dh import from_dh, to_dh
from kincal.kinematics.model import PRISMATIC, REVOLUTE

FORMAT = "kincal-dh"
CHECK_CONFIGURATIONS = 200
FORMULAS = {"standard": "A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)",
            "modified": "A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)"}
_UNITS = {"a": {"a_m": 1.0, "a_mm": 1e-3}, "alpha": {"alpha_rad": 1.0, "alpha_deg": np.pi / 180},
          "d": {"d_m": 1.0, "d_mm": 1e-3}, "theta": {"theta_rad": 1.0, "theta_deg": np.pi / 180}}
_ROW_KEYS = {"joint", "type", "limits"} | {k for u in _UNITS.values() for k in u}
_TOP_KEYS = {"format", "convention", "formula", "chain", "arm", "joints", "base", "flange", "tool", "check"}


def dh_document(a: ArmModel, modified: bool) -> dict:
    """The DH table of ``a`` as plain data (m, rad), with its closing transforms and its FK check."""
    t = to_dh(a, modified=modified)
    rng = np.random.default_rng(0)
    q = rng.uniform(np.maximum(a.lower, -np.pi), np.minimum(a.upper, np.pi), (CHECK_CONFIGURATIONS, a.dof))
    diff = forward_kinematics(t.to_model(), q) - forward_kinematics(a, q)
    rows = []
    for i, (n, k, x, al, d, th) in enumerate(zip(t.joint_names, t.joint_types, t.a, t.alpha, t.d, t.theta)):
        row = {"joint": n, "type": k, "a_m": float(x) + 0.0, "alpha_rad": float(al) + 0.0, "d_m": float(d) + 0.0,
               "theta_rad": float(th) + 0.0}  # + 0.0: no negative zeros
        if np.isfinite(a.lower[i]) or np.isfinite(a.upper[i]):
            row["limits"] = [_bound(a.lower[i]), _bound(a.upper[i])]
        rows.append(row)
    convention = "modified" if modified else "standard"
    return {"format": FORMAT, "convention": convention, "formula": FORMULAS[convention] + " (Craig)" * modified,
            "chain": "T_world_tool = base @ A_1 ... A_n @ flange @ tool; theta (d for prismatic joints) includes the "
                     "joint offsets",
            "arm": a.name, "joints": rows, "base": _matrix(t.base), "flange": _matrix(t.flange),
            "tool": _matrix(t.tool),
            "check": {"configurations": CHECK_CONFIGURATIONS,
                      "max_position_difference_m": float(np.abs(diff[:, :3, 3]).max()),
                      "max_rotation_difference": float(np.abs(diff[:, :3, :3]).max())}}


def dh_text(a: ArmModel, modified: bool) -> str:
    """The DH table file of ``a``: ``dh_document`` as YAML, one line per joint row."""
    doc = dh_document(a, modified)
    rows = doc.pop("joints")
    head, tail = {k: doc.pop(k) for k in list(doc)[:list(doc).index("arm") + 1]}, doc
    lines = [yaml.safe_dump(head, sort_keys=False, width=200).rstrip(), "joints:"]
    lines += ["  - " + yaml.safe_dump(r, sort_keys=False, default_flow_style=True, width=1000).strip() for r in rows]
    return "\n".join(lines) + "\n" + yaml.safe_dump(tail, sort_keys=False, default_flow_style=None, width=200)


def _bound(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _matrix(T: np.ndarray) -> list[list[float]]:
    return [[float(x) for x in row] for row in T]


def read_dh_table(path, name: str | None = None) -> Robot:
    """A one-arm Robot from a DH table file (robot name: ``name`` or the file's stem)."""
    file = str(path)
    return dh_table_robot(parse_yaml(read_text(path, "DH table"), file), file, name or Path(path).stem)


def dh_table_robot(data: Any, file: str, name: str) -> Robot:
    ctx = _Ctx(file)
    top = _mapping(ctx, data, "(top level)", _TOP_KEYS, required=("format", "convention", "joints"))
    if top["format"] != FORMAT:
        raise ctx.fail("format", f"expected {quote(FORMAT)}, found {quote(top['format'])}")
    convention = ctx.one_of("convention", top["convention"], tuple(FORMULAS))
    arm = _string(ctx, top.get("arm", "arm"), "arm")
    rows = top["joints"]
    if not isinstance(rows, list) or not rows:
        raise ctx.fail("joints", f"expected a list of rows (one per joint), found {quote(rows)}")
    cols = {k: [] for k in ("a", "alpha", "d", "theta", "lower", "upper", "names", "types")}
    for i, row in enumerate(rows):
        for k, v in _row(ctx, row, i).items():
            cols[k].append(v)
    poses = {k: _closing(ctx, top.get(k), k) for k in ("base", "flange", "tool")}
    model = _dh_model(ctx, cols, convention == "modified", arm, poses)
    return Robot(name, {arm: model})


def _row(ctx: _Ctx, row: Any, i: int) -> dict:
    where = f"joints row {i + 1}"
    r = _mapping(ctx, row, where, _ROW_KEYS)
    kind = ctx.one_of(f"{where}.type", r.get("type", REVOLUTE), (REVOLUTE, PRISMATIC))
    out = {"names": _string(ctx, r.get("joint", f"j{i + 1}"), f"{where}.joint"), "types": kind}
    factor = {}
    for col, units in _UNITS.items():
        given = [k for k in units if k in r]
        if len(given) != 1:
            found = f"found {', '.join(given)}" if given else "found none"
            raise ctx.fail(where, f"expected one of {', '.join(units)} ({found})")
        factor[col] = units[given[0]]
        out[col] = _number(ctx, r[given[0]], f"{where}.{given[0]}") * factor[col]
    out["lower"], out["upper"] = _limits(ctx, r.get("limits"), f"{where}.limits",
                                         factor["d" if kind == PRISMATIC else "theta"])
    return out


def _limits(ctx: _Ctx, value: Any, path: str, factor: float) -> tuple[float, float]:
    if value is None:
        return -np.inf, np.inf
    if not isinstance(value, list) or len(value) != 2:
        raise ctx.fail(path, f"expected [lower, upper] (null for no bound), found {quote(value)}")
    lo, hi = (-np.inf if value[0] is None else _number(ctx, value[0], f"{path}[0]") * factor,
              np.inf if value[1] is None else _number(ctx, value[1], f"{path}[1]") * factor)
    if not lo < hi:
        raise ctx.fail(path, f"expected lower < upper, found {quote(value)}")
    return lo, hi


def _closing(ctx: _Ctx, value: Any, key: str) -> np.ndarray:
    """A closing transform: a 4x4 matrix (m) or a pose mapping (xyz m, rpy rad, ...); omitted: identity."""
    return _pose(ctx, {"matrix": value} if isinstance(value, list) else value, key)


def _dh_model(ctx: _Ctx, cols: dict, modified: bool, arm: str, poses: dict) -> ArmModel:
    try:
        return from_dh(cols["a"], cols["alpha"], cols["d"], cols["theta"], modified=modified,
                       joint_types=cols["types"], flange=poses["flange"], name=arm, base=poses["base"],
                       tool=poses["tool"], lower=cols["lower"], upper=cols["upper"],
                       joint_names=tuple(cols["names"]))
    except ModelError as exc:  # e.g. a joint name used twice
        raise ctx.fail("joints", str(exc)) from None
