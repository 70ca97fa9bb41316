"""Starting values beyond the nominal model: a tool frame far from nominal, seen by full-pose data.

The solver's steps are local: from a nominal tool frame turned by more than about 110 deg from the real one,
full-pose data with an unknown tracker end in a local minimum. When an arm's tool (or home) pose is free and a
pose data set of that arm has an unknown tracker, the hand-eye solution (``experiments.handeye``) gives the
tool's error; if it is a large rotation the solve starts from the corrected tool, with every unknown tracker
of that arm re-initialised to match. The nominal model stays the reference of the report.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kincal.experiments._kernel import pose_mean
from kincal.experiments.handeye import hand_eye
from kincal.lie import se3, so3
from kincal.params import Layout, State

# Below this rotation of the tool frame's error the local steps find the solution from the nominal tool.
CORRECT_ABOVE_RAD = np.radians(30.0)


def starting_state(nominal: State, experiments, layout: Layout, unknown) -> tuple[State, State]:
    """(start, nominal) where ``start`` has corrected tool frames and both have the matching tracker guesses."""
    arms, extras = dict(nominal.arms), dict(nominal.extras)
    for exp in experiments:
        arm = exp.arms[0]
        if exp.kind != "pose" or exp.frames["tracker"] not in unknown or arms[arm] is not nominal.arms[arm]:
            continue
        part = next((p for p in ("tool", "home") if layout.free[layout.block(f"{arm}.{p}").start]), None)
        if part is None:
            continue
        M = exp.dataset.measured["T_tracker_tool"]
        X = hand_eye(exp._fk(nominal, arm), M)
        if X is None or np.linalg.norm(so3.log(X[:3, :3])) < CORRECT_ABOVE_RAD:
            continue
        a = arms[arm]
        if part == "tool":
            arms[arm] = replace(a, tool=a.tool @ X)
        else:  # home @ tool becomes home @ tool @ X
            arms[arm] = replace(a, home=a.home @ a.tool @ X @ se3.inverse(a.tool))
    if all(arms[k] is nominal.arms[k] for k in arms):
        return nominal, nominal
    start = nominal.replace(arms, extras)
    for exp in experiments:  # trackers of corrected arms, guessed again with the corrected tool
        corrected = arms[exp.arms[0]] is not nominal.arms[exp.arms[0]]
        if exp.kind == "pose" and exp.frames["tracker"] in unknown and corrected:
            F = exp._fk(start, exp.arms[0])
            extras[exp.frames["tracker"]] = pose_mean(F @ se3.inverse(exp.dataset.measured["T_tracker_tool"]))
    return nominal.replace(arms, extras), nominal.replace(extras=extras)
