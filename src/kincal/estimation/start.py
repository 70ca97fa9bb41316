"""Starting values beyond the nominal model: a tool frame far from nominal.

The solver's steps are local: from a nominal tool frame turned by more than about 110 deg from the real one,
the solve ends in a local minimum. Each experiment kind may tell, from its data, that an arm's free tool (or
home) pose is far off (``Experiment.start``; full-pose data with an unknown tracker do, by the hand-eye
solution); the solve then starts from the corrected tool, with the unknown frames of every experiment of that
arm guessed again (``Experiment.initial``). The nominal model stays the reference of the report.
"""

from __future__ import annotations

from dataclasses import replace

from kincal.experiments import Experiment
from kincal.experiments.sharing import as_extra
from kincal.lie import se3
from kincal.params import Layout, State


def starting_state(nominal: State, experiments, layout: Layout, unknown) -> tuple[State, State]:
    """(start, nominal) where ``start`` has corrected tool frames and both have the matching frame guesses."""
    arms = dict(nominal.arms)
    for exp in experiments:
        if getattr(exp.start, "__func__", None) is Experiment.start:  # a kind that never corrects a tool
            continue
        free = [f"{arm}.{p}" for arm in exp.arms if arms[arm] is nominal.arms[arm] for p in ("tool", "home")
                if layout.free[layout.block(f"{arm}.{p}").start]]
        for part, X in exp.start(nominal, free, unknown).items():
            arm = part.split(".")[0]
            a = arms[arm]
            if f"{arm}.tool" in free:
                arms[arm] = replace(a, tool=a.tool @ X)
            else:  # home @ tool becomes home @ tool @ X
                arms[arm] = replace(a, home=a.home @ a.tool @ X @ se3.inverse(a.tool))
    if all(arms[k] is nominal.arms[k] for k in arms):
        return nominal, nominal
    start = nominal.replace(arms)
    extras, done = dict(nominal.extras), set()
    for exp in experiments:  # unknown frames of corrected arms, guessed again with the corrected tool
        if all(arms[a] is nominal.arms[a] for a in exp.arms):
            continue
        given = {r: start.extras[n] for r, n in exp.frames.items() if n not in unknown}
        for role, value in exp.initial(start, given).items():
            if exp.frames[role] not in done:  # a shared frame: the first data set's guess, as in the nominal
                extras[exp.frames[role]] = as_extra(exp, role, value)
                done.add(exp.frames[role])
    return nominal.replace(arms, extras), nominal.replace(extras=extras)
