"""``kincal model show`` and ``kincal fk``: inspect a model file or built-in robot, evaluate forward kinematics."""

from __future__ import annotations

import json
import math
import re

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from kincal.errors import ShapeError
from kincal.cli.calibrate_cmds import _console
from kincal.io.models import load_robot, select_arm
from kincal.lie.rotations import matrix_to_quat_wxyz, matrix_to_rpy
from kincal.kinematics import forward_kinematics
from kincal.kinematics.tree import tip_model
from kincal.kinematics.model import REVOLUTE, ArmModel


def _fmt(x: float, digits: int = 4) -> str:
    if not math.isfinite(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}f}" if abs(x) >= 0.5 * 10.0**-digits else f"{0.0:.{digits}f}"


def _short(x: float, digits: int = 4) -> str:
    """Up to ``digits`` decimals without trailing zeros: 1, -0.03, 0.2565."""
    text = _fmt(x, digits)
    return text.rstrip("0").rstrip(".") if "." in text else text


def _vec(a, digits: int = 4, short: bool = False) -> str:
    f = _short if short else _fmt
    return "(" + ", ".join(f(float(x), digits) for x in a) + ")"


def _pose_lines(T: np.ndarray) -> dict:
    return {
        "matrix": [[float(x) for x in row] for row in T],
        "xyz_m": [float(x) for x in T[:3, 3]],
        "rpy_deg": [float(x) for x in np.degrees(matrix_to_rpy(T[:3, :3]))],
        "quaternion_wxyz": [float(x) for x in matrix_to_quat_wxyz(T[:3, :3])],
    }


def _joint_rows(arm: ArmModel) -> list[dict]:
    channel = {model_index: c + 1 for c, model_index in enumerate(arm.controller_order)}
    rows = []
    for i, name in enumerate(arm.joint_names):
        xi = arm.screws[i]
        v, w = xi[:3], xi[3:]
        revolute = arm.joint_types[i] == REVOLUTE
        unit = "deg" if revolute else "mm"
        scale = 180 / math.pi if revolute else 1000.0
        rows.append({
            "name": name,
            "type": arm.joint_types[i],
            "axis": [float(x) + 0.0 for x in (w if revolute else v)],
            "point_m": [float(x) + 0.0 for x in np.cross(w, v)] if revolute else None,
            "twist": [float(x) + 0.0 for x in xi],
            f"lower_{unit}": float(arm.lower[i] * scale) if math.isfinite(arm.lower[i]) else None,
            f"upper_{unit}": float(arm.upper[i] * scale) if math.isfinite(arm.upper[i]) else None,
            f"offset_{unit}": float(arm.offsets[i] * scale),
            "gear_ratio": float(arm.gear_ratios[i]),
            "controller_channel": channel[i],
            f"compliance_{'rad_per_Nm' if revolute else 'm_per_N'}": float(arm.compliance[i]),
        })
    return rows


def _arm_dict(arm: ArmModel) -> dict:
    return {
        "dof": arm.dof,
        "joints": _joint_rows(arm),
        "controller_order": [arm.joint_names[i] for i in arm.controller_order],
        "base": _pose_lines(arm.base),
        "home": _pose_lines(arm.home),
        "tool": _pose_lines(arm.tool),
    }


def _print_arm(console: Console, robot_name: str, key: str, arm: ArmModel) -> None:
    table = Table(title=f"{robot_name} / {key}: {arm.dof} joints", title_justify="left", caption_justify="left",
                  caption="point: the point of each revolute axis nearest the arm base origin; "
                          "channel: controller axis")
    for col in ("joint", "type", "axis", "point [m]", "twist (v, w)", "limits", "offset", "gear", "channel"):
        table.add_column(col, no_wrap=True)
    for r in _joint_rows(arm):
        unit = "deg" if r["type"] == REVOLUTE else "mm"
        lo, up = r[f"lower_{unit}"], r[f"upper_{unit}"]
        limits = "none" if lo is None and up is None else f"{_fmt(lo if lo is not None else -math.inf, 2)} .. " \
                 f"{_fmt(up if up is not None else math.inf, 2)} {unit}"
        table.add_row(
            r["name"], r["type"], _vec(r["axis"], 6, True), _vec(r["point_m"], 6, True) if r["point_m"] else "-",
            _vec(r["twist"], 6, True),
            limits, f"{_fmt(r[f'offset_{unit}'], 3)} {unit}", f"{r['gear_ratio']:g}", str(r["controller_channel"]),
        )
    console.print(table)
    order = ", ".join(arm.joint_names[i] for i in arm.controller_order)
    console.print(f"controller order (channel 1..n -> joint): {order}")
    if np.any(arm.compliance):
        parts = [f"{n} {c:.4g} {'rad/(N m)' if t == REVOLUTE else 'm/N'}"
                 for n, c, t in zip(arm.joint_names, arm.compliance, arm.joint_types) if c]
        console.print(f"joint compliance: {', '.join(parts)}")
    for name, nodes in arm.compliance_nodes.items():  # (angle rad, compliance) rows: docs/model-format.md
        table_text = ", ".join(f"{np.degrees(a):g} deg: {c:.4g}" for a, c in nodes)
        console.print(f"joint compliance of {name} by its angle, rad/(N m), linear between nodes: {table_text}")
    poses = (("base  T_world_base", arm.base), ("home  T_base_flange(0)", arm.home), ("tool  T_flange_tool", arm.tool))
    for label, T in poses:
        p = _pose_lines(T)
        console.print(f"{label}: xyz {_vec(p['xyz_m'])} m, rpy {_vec(p['rpy_deg'], 3)} deg, "
                      f"quaternion wxyz {_vec(p['quaternion_wxyz'], 6)}")
    console.print()


def _parse_q(text: str, option: str) -> np.ndarray:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    try:
        return np.array([float(p) for p in parts])
    except ValueError:
        raise click.BadParameter(f"expected numbers separated by commas or spaces, got {text!r}",
                                 param_hint=option) from None


@click.group("model")
def model_group() -> None:
    """Inspect robot models (built-in names or model files)."""


@model_group.command("show", short_help="Joints, screws, limits and poses of a model.")
@click.argument("source", metavar="NAME|FILE")
@click.option("--arm", default=None, help="Show only this arm.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (SI units, limits in deg/mm).")
def show(source: str, arm: str | None, as_json: bool) -> None:
    """Joints, screws (axis, point, twist), limits, gear ratios, controller order and poses of a model."""
    robot = load_robot(source)
    keys = list(robot.arms) if arm is None else [arm]
    arms = {k: robot[k] for k in keys}
    if as_json:
        payload = {"name": robot.name, "meta": _plain(robot.meta), "arms": {k: _arm_dict(a) for k, a in arms.items()}}
        click.echo(json.dumps(payload, indent=2))
        return
    console = _console()
    for key, model in arms.items():
        _print_arm(console, robot.name, key, model)


def _plain(x):
    if isinstance(x, dict) or hasattr(x, "items"):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


@click.command("fk")
@click.argument("source", metavar="NAME|FILE")
@click.option("--arm", default=None, help="Arm name (required when the robot has several arms).")
@click.option("--q-deg", default=None, help="Joint readings in degrees, comma or space separated (mm for prismatic).")
@click.option("--q-rad", default=None, help="Joint readings in radians, comma or space separated (m for prismatic).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def fk(source: str, arm: str | None, q_deg: str | None, q_rad: str | None, as_json: bool) -> None:
    """Tool pose T_world_tool for one joint configuration: matrix, xyz, rpy (deg), quaternion (w, x, y, z).
    A mounted arm (a tree) takes its carriers' readings first (torso, then arm)."""
    if (q_deg is None) == (q_rad is None):
        raise click.UsageError("give the joint readings with exactly one of --q-deg or --q-rad")
    robot = load_robot(source)
    model = select_arm(robot, arm)
    if arm is not None and len(robot.lineage(arm)) > 1:
        model = tip_model(robot, arm)  # a mounted arm's tool in the world: its carriers' readings first
    raw = _parse_q(q_deg if q_deg is not None else q_rad, "--q-deg" if q_deg is not None else "--q-rad")
    if raw.size != model.dof:
        raise ShapeError(f"arm '{model.name}' of robot '{robot.name}' has {model.dof} joints "
                         f"({', '.join(model.joint_names)}); got {raw.size} values")
    q = raw.copy()
    if q_deg is not None:  # edge conversion: deg -> rad for revolute, mm -> m for prismatic joints
        revolute = np.array([t == REVOLUTE for t in model.joint_types])
        q = np.where(revolute, np.radians(raw), raw / 1000.0)
    T = forward_kinematics(model, q)
    pose = _pose_lines(T)
    if as_json:
        payload = {"robot": robot.name, "arm": model.name, "q_rad": [float(x) for x in q], **pose}
        click.echo(json.dumps(payload, indent=2))
        return
    console = _console()
    console.print(f"{robot.name} / {model.name}: T_world_tool")
    matrix = Table(show_header=False, box=None, pad_edge=False)
    for _ in range(4):
        matrix.add_column(justify="right")
    for row in T:
        matrix.add_row(*(f"{x + 0.0: .9f}" for x in np.where(np.abs(row) < 5e-10, 0.0, row)))  # no "-0.000000000"
    console.print(matrix)
    console.print(f"xyz [m]:          {_vec(pose['xyz_m'], 6)}")
    console.print(f"rpy [deg]:        {_vec(pose['rpy_deg'], 6)}")
    console.print("                  (R = Rz(yaw) Ry(pitch) Rx(roll))")
    console.print(f"quaternion wxyz:  {_vec(pose['quaternion_wxyz'], 9)}")


def register(group: click.Group) -> None:
    group.add_command(model_group)
    group.add_command(fk)
