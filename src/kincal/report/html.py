"""One self-contained HTML report of a calibration (``kincal report``; docs/deploy.md): no external file, plots
inline as PNG.

Order: what a person needs first. The verdict (status, whether the model can be trusted, what cannot be
identified, what to measure next), then the estimates, residuals and validation, the singular value spectrum,
a predicted accuracy map over the workspace, and where it all came from (job, input files with SHA-256,
kincal version, date). A tree-structured robot (``Robot.mounts``) gets a table of which arm carries which and
whose parameters each carrier's estimates move (a torso's once, for every arm on it); validation and the accuracy
map of a mounted arm go through its carriers (the composite chain).
"""

from __future__ import annotations

import base64
import html
import io
import math
from typing import Mapping, Sequence

import numpy as np

from kincal.kinematics import forward_kinematics
from kincal.kinematics.tree import tip_pose
from kincal.report.plots import _prediction, _pyplot, _residuals, _spectrum, _uncertainty

DEG = 180.0 / math.pi
STATUS_COLOUR = {"converged": "#1a7f37", "misfit": "#b35900", "not converged": "#b35900", "degenerate": "#c62828"}
_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#1d1d1f;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.2em;border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
.verdict{border-radius:8px;padding:1em 1.2em;color:#fff;font-size:1.1em}
.verdict b{font-size:1.25em}table{border-collapse:collapse;font-size:.88em;margin:.5em 0}
td,th{border:1px solid #ddd;padding:.25em .6em;text-align:right}th{background:#f4f4f6}
td:first-child,th:first-child{text-align:left}img{max-width:100%}.muted{color:#666;font-size:.9em}
ul{margin:.3em 0}
"""


def report_html(result, *, title: str, workspace: Mapping[str, np.ndarray] | None = None,
                provenance: Mapping | None = None, next_steps: Sequence[str] = ()) -> str:
    """The report of ``result``. ``workspace``: per arm, joint configurations for the accuracy map;
    ``provenance``: job, inputs (file, sha256), version, date; ``next_steps``: what to measure next, in words."""
    plt = _pyplot()
    parts = [f"<h1>{_e(title)}</h1>", _verdict(result, next_steps)]
    if result.robot.mounts:
        parts += ["<h2>Tree: which arm carries which</h2>", tree_table(result)]
    parts += ["<h2>Estimates</h2>", _estimates(result), _image(plt, _uncertainty(plt, result))]
    parts += ["<h2>Residuals before and after</h2>", _residual_table(result), _image(plt, _residuals(plt, result))]
    if result.stages:
        parts += ["<h2>Stages</h2>", "<p>Each stage started from the one before; the estimates, standard deviations "
                  "and verdicts above are the last stage's.</p>", _stage_table(result)]
    if result.validation:
        parts += ["<h2>Validation on held-out configurations</h2>", _validation(result)]
        if result.predictions:
            parts.append(_image(plt, _prediction(plt, result)))
    parts += ["<h2>Identifiability: singular value spectrum</h2>", _image(plt, _spectrum(plt, result))]
    if workspace:
        parts += ["<h2>Predicted accuracy over the workspace</h2>",
                  "<p>Predicted standard deviation of the calibrated tool position at random configurations "
                  "within the joint limits (one common rigid motion removed, as a validation with an unknown "
                  "tracker or fixture sees it). Dark: accurate; bright: less accurate.</p>"]
        parts += [_image(plt, accuracy_map(plt, result, arm, q)) for arm, q in workspace.items()]
    parts += ["<h2>Provenance</h2>", _provenance(provenance or {})]
    body = "\n".join(parts)
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{_e(title)}</title>"
            f"<style>{_CSS}</style></head><body>\n{body}\n</body></html>\n")


def _verdict(result, next_steps) -> str:
    ana = result.identifiability
    ok = result.trusted
    colour = STATUS_COLOUR["converged"] if ok else STATUS_COLOUR.get(result.status, "#555")
    if result.status == "converged" and not ok:
        colour = STATUS_COLOUR["misfit"]
    head = (f'<div class="verdict" style="background:{colour}"><b>{_e(result.status)}</b> &middot; trusted: '
            f"<b>{'yes' if ok else 'no'}</b> &middot; rank {ana.rank} of {len(ana.names)} free parameters &middot; "
            f"residual variance factor {result.sigma2:.3g}</div>")
    words = {d.words for d in ana.directions}
    general = [m for m in result.messages if m not in words]
    doubts = [f"{name}, arm '{p.arm}': {m}" for name, p in result.predictions for m in p.messages
              if "not be trusted" in m or "held at nominal" in m]
    out = [head, "<h2>Summary</h2>", _list(general + list(dict.fromkeys(doubts)), "No messages.")]
    directions = [d.words for d in ana.directions]
    shown, rest = directions[:5], directions[5:]
    out.append(f"<h3>What cannot be identified ({len(directions)} direction(s))</h3>"
               + _list(shown, "Every free parameter is identifiable."))
    if rest:
        out.append(f"<details><summary>{len(rest)} more</summary>{_list(rest, '')}</details>")
    steps = list(next_steps) or [m.split("; ", 1)[1] for _, p in result.predictions for m in p.messages
                                 if m.startswith(_TODO) and "; " in m]
    out.append("<h3>What to measure next</h3>" + _list(list(dict.fromkeys(steps)), "Nothing the data ask for."))
    return "\n".join(out)


# The prediction's closing advice starts so; what follows the semicolon is what to do.
_TODO = "the calibrated model should not be trusted at these configurations"


def _list(items, empty: str) -> str:
    return "<ul>" + "".join(f"<li>{_e(x)}</li>" for x in items) + "</ul>" if items else f"<p>{_e(empty)}</p>"


def _shown(unit: str, value: float) -> tuple[str, float]:
    if unit == "rad":
        return "deg", value * DEG
    if unit == "m":
        return "mm", value * 1e3
    return unit, value


def _estimates(result) -> str:
    """The estimates with, where the data do not fix every coordinate, their change split in the named gauge
    (what the data determine, with its standard deviation, and a gauge move that changes no residual), then
    the derived quantities (axis geometry, tool pose at the nominal zero)."""
    g = result.gauge
    intro = "" if g is None else f"<p class=\"muted\">Gauge of the determined changes: {_e(g.description)}</p>"
    head = ("<tr><th>parameter</th><th>unit</th><th>nominal</th><th>estimate</th><th>change</th>"
            + ("<th>determined change</th><th>std</th><th>gauge move</th>" if g is not None else "<th>std</th>")
            + "</tr>")
    rows = [head]
    for e in result.estimates:
        unit, value = _shown(e.unit, e.value)
        _, nominal = _shown(e.unit, e.nominal)
        cells = f"<td>{_e(e.name)}</td><td>{unit}</td><td>{nominal:.6g}</td><td>{value:.6g}</td><td>{value - nominal:+.4g}</td>"
        if g is not None:
            d, s, m = (_shown(e.unit, x)[1] for x in g.split(e.name))
            cells += f"<td>{d:+.4g}</td><td>{_num(s)}</td><td>{m:+.4g}</td>"
        else:
            _, std = _shown(e.unit, e.std)
            cells += f"<td>{_num(std) if e.identifiable else 'not identifiable'}</td>"
        rows.append(f"<tr>{cells}</tr>")
    out = intro + "<table>" + "".join(rows) + "</table>"
    if result.derived:
        drows = ["<tr><th>derived quantity</th><th>unit</th><th>nominal</th><th>value</th><th>std</th>"
                 "<th>gauge invariant</th></tr>"]
        for q in result.derived:
            unit, value = _shown(q.unit, q.value)
            _, nominal = _shown(q.unit, q.nominal)
            _, std = _shown(q.unit, q.std)
            drows.append(f"<tr><td title=\"{_e(q.words)}\">{_e(q.name)}</td><td>{unit}</td><td>{nominal:.6g}</td>"
                         f"<td>{value:.6g}</td><td>{_num(std)}</td><td>{'yes' if q.identifiable else 'no'}</td></tr>")
        out += "<h3>Derived quantities</h3><table>" + "".join(drows) + "</table>"
    return out


def tree_table(result) -> str:
    """One row per arm of a tree-structured robot: what carries it, what it carries (every arm whose pose its
    joints and parameters move), its joints and its estimates (each shared parameter once, under its arm)."""
    robot = result.robot
    rows = ["<tr><th>arm</th><th>mounted on</th><th>carries</th><th>joints</th><th>estimated parameters</th></tr>"]
    for arm in robot.arms:
        line = robot.lineage(arm)
        carried = [a for a in robot.arms if a != arm and arm in robot.lineage(a)]
        count = sum(1 for e in result.estimates if e.name.startswith(f"{arm}."))
        rows.append(f"<tr><td>{_e(arm)}</td><td>{_e(' -> '.join(line[:-1])) or '(the base)'}</td>"
                    f"<td>{_e(', '.join(carried)) or '-'}</td><td>{_e(', '.join(robot[arm].joint_names))}</td>"
                    f"<td>{count}</td></tr>")
    return ("<p>A carrier's parameters (a torso's) exist once: they move every arm it carries, and the estimates "
            "table lists them once.</p><table>" + "".join(rows) + "</table>")


def _tip(robot, arm: str) -> str:
    line = robot.lineage(arm) if arm in robot.arms else (arm,)
    return arm if len(line) == 1 else f"{arm} (on {' -> '.join(line[:-1])})"


def _residual_table(result) -> str:
    rows = ["<tr><th>data set</th><th>kind</th><th>samples</th><th>position RMS before (mm)</th>"
            "<th>after</th><th>orientation RMS before (deg)</th><th>after</th></tr>"]
    for b, a in zip(result.before, result.after):
        rows.append(f"<tr><td>{_e(b.experiment)}</td><td>{_e(b.kind)}</td><td>{b.samples}</td>"
                    f"<td>{_num(b.position_rms, 1e3)}</td><td>{_num(a.position_rms, 1e3)}</td>"
                    f"<td>{_num(b.orientation_rms, DEG)}</td><td>{_num(a.orientation_rms, DEG)}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def _stage_table(result) -> str:
    rows = ["<tr><th>stage</th><th>free</th><th>held</th><th>parameters</th><th>rank</th><th>status</th>"
            "<th>variance factor</th><th>position RMS (mm)</th><th>orientation RMS (deg)</th></tr>"]
    for i, st in enumerate(result.stages, 1):
        free = st.free if isinstance(st.free, str) else ", ".join(st.free)
        rows.append(f"<tr><td>{i} {_e(st.name)}</td><td>{_e(free)}</td><td>{_e(', '.join(st.fixed)) or '-'}</td>"
                    f"<td>{st.parameters}</td><td>{st.rank}</td><td>{_e(st.status)}</td><td>{_num(st.sigma2)}</td>"
                    f"<td>{_num(st.rms('position'), 1e3)}</td><td>{_num(st.rms('orientation'), DEG)}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def _validation(result) -> str:
    """One row per held-out set; the arm (a tip, through its carriers) where the prediction says which."""
    arms = {name: p.arm for name, p in result.predictions}
    rows = ["<tr><th>held-out set</th><th>arm</th><th>samples</th><th>position RMS, nominal model (mm)</th>"
            "<th>calibrated</th><th>orientation RMS, nominal (deg)</th><th>calibrated</th></tr>"]
    for v in result.validation:
        arm = arms.get(v.experiment)
        rows.append(f"<tr><td>{_e(v.experiment)}</td><td>{_e(_tip(result.robot, arm)) if arm else '-'}</td>"
                    f"<td>{v.after.samples}</td>"
                    f"<td>{_num(v.before.position_rms, 1e3)}</td><td>{_num(v.after.position_rms, 1e3)}</td>"
                    f"<td>{_num(v.before.orientation_rms, DEG)}</td><td>{_num(v.after.orientation_rms, DEG)}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def accuracy_map(plt, result, arm: str, q):
    """Top and side views of the tool positions at configurations q, coloured by the predicted standard
    deviation of the calibrated tool position (mm). A mounted arm: q maps its lineage's arms to readings
    (``kincal.simulate.workspace_sample``), the tool through its carriers."""
    pred = result.predict(q, arm)
    mounted = isinstance(q, Mapping)
    p = (tip_pose(result.robot, arm, q) if mounted else forward_kinematics(result.robot[arm], q))[:, :3, 3]
    n = len(p)
    std = pred.position_std * 1e3
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, (i, j, label) in zip(axes, ((0, 1, "top view: x, y"), (0, 2, "side view: x, z"))):
        sc = ax.scatter(p[:, i], p[:, j], c=std, cmap="viridis", s=14)
        ax.set_xlabel("xyz"[i] + " [m]")
        ax.set_ylabel("xyz"[j] + " [m]")
        ax.set_title(label)
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=axes, label="predicted tool position std [mm]")
    fig.suptitle(f"arm '{_tip(result.robot, arm)}': predicted accuracy at {n} configurations (RMS {np.sqrt(np.mean(std**2)):.3g} "
                 f"mm, max {std.max():.3g} mm){'' if pred.trusted else ' - NOT TRUSTED'}")
    return fig


def _provenance(p: Mapping) -> str:
    rows = [f"<tr><td>{_e(k)}</td><td>{_e(str(v))}</td></tr>" for k, v in p.items() if k != "inputs"]
    for f in p.get("inputs", ()):
        rows.append(f"<tr><td>input</td><td>{_e(f['file'])} <span class=\"muted\">sha256 {_e(f['sha256'])}</span>"
                    "</td></tr>")
    return "<table>" + "".join(rows) + "</table>" if rows else "<p class=\"muted\">not recorded</p>"


def _image(plt, fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return f'<p><img alt="plot" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}"></p>'


def _num(x, scale=1.0) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * scale:.4g}"


def _e(text) -> str:
    return html.escape(str(text))
