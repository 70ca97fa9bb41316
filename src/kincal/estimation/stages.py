"""Staged solves: a sequence of solves over one problem, each with its own free set, each starting where the
previous one ended (``calibrate(..., stages=[Stage(...), ...])``, a job's ``stages:``; docs/calibration.md
"Staged solves").

Every stage has the same data, noise, priors, constraints and nominal state (the reference of priors, of the
reported change and of the gauge); only the free set and the starting state change. Stage 1 starts where a
single solve with its free set would (``Problem.build``: the nominal, corrected tool frames); stage k starts
from stage k-1's final state, frames included. Frames no data set gives are free in every stage as in a single
solve, but a later stage may hold them (``fixed``) at the estimate of the stages before it. The final
``Result`` is the last stage's, with ``Result.stages`` recording each stage.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError
from kincal.estimation.memory import require_memory
from kincal.estimation.options import SolverOptions
from kincal.estimation.problem import Problem
from kincal.estimation.result import Result, StageRecord
from kincal.estimation.start import starting_state
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.params import Layout, Prior, build_layout


class StageError(ModelError):
    """A stage's free set is wrong: ``field`` names it (``stages[1].free``) for the job reader's message."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field, self.reason = field, reason


@dataclass(frozen=True)
class Stage:
    """One solve of a staged calibration: what is ``free`` (a level word, or names/globs with level words
    allowed inside, as ``calibrate``'s ``free``) minus ``fixed`` (globs); ``name`` labels it in reports."""

    free: str | tuple[str, ...]
    fixed: tuple[str, ...] = ()
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.free, str):
            object.__setattr__(self, "free", tuple(self.free))
        object.__setattr__(self, "fixed", (self.fixed,) if isinstance(self.fixed, str) else tuple(self.fixed))
        if not self.free:
            raise StageError("free", f"stage {self.name!r} names nothing to free; a stage frees at least one "
                             "parameter")


def label(stages: Sequence[Stage], i: int) -> str:
    """How reports name stage ``i``: ``stages[i]`` with its name."""
    return f"stages[{i}]" + (f" ({stages[i].name!r})" if stages[i].name else "")


def stage_problems(robot: Robot, datasets: Sequence[Dataset], stages: Sequence[Stage],
                   priors: Mapping[str, Prior] | None = None, noise: Noise | Mapping[str, Noise] | None = None,
                   constraints=()) -> list[Problem]:
    """One problem per stage, every free set checked before anything is solved (``ModelError`` naming the stage
    and its field: a pattern that matches nothing, a stage that frees nothing, an unknown frame held in stage
    1). Stage 1's problem starts where a single solve would; later ones start at the nominal until
    ``solve_stages`` gives them the previous stage's state."""
    if not stages:
        raise ModelError("stages: give at least one stage")
    base = Problem.build(robot, datasets, [], (), priors, noise, constraints)  # only the unknown frames free
    layouts = [stage_layout(base, stages, i) for i in range(len(stages))]
    require_memory(datasets, max(int(layout.free.sum()) for layout in layouts))
    start, nominal = starting_state(base.nominal, base.experiments, layouts[0], base.unknown)
    return [Problem.assemble(robot, base.experiments, layout, nominal, base.noise, start if i == 0 else nominal,
                             base.constraints, base.unknown) for i, layout in enumerate(layouts)]


def stage_layout(base: Problem, stages: Sequence[Stage], i: int) -> Layout:
    """The layout of stage ``i`` over ``base``'s coordinates: its free set minus its fixed set, the unknown
    frames (unless the stage holds them; not the first) and every coordinate with a prior."""
    stage, where = stages[i], f"stages[{i}]"
    arms = list(dict.fromkeys(b.arm for b in base.layout.blocks if b.arm is not None))
    field = "free"
    try:
        build_layout(base.nominal, stage.free, free_extras=(), arms=arms)
        field = "fixed"
        free = build_layout(base.nominal, stage.free, fixed=stage.fixed, free_extras=base.unknown, arms=arms).free
    except ModelError as exc:
        raise StageError(f"{where}.{field}", str(exc)) from None
    free = free | np.isfinite(base.layout.prior_sigma)
    if i == 0:
        held = [n for n in base.unknown if not free[base.layout.block(n).slice].all()]
        if held:
            raise StageError(f"{where}.fixed", f"{held[0]!r} is unknown (not given in its data set) and no earlier "
                             "stage estimated it: the first stage cannot hold it")
    if not free.any():
        raise StageError(where, f"frees nothing (free {_spec(stage.free)}, fixed {list(stage.fixed)})")
    return replace(base.layout, free=free)


def _spec(free) -> str:
    return repr(free) if isinstance(free, str) else repr(list(free))


def solve_stages(problems: Sequence[Problem], stages: Sequence[Stage], options: SolverOptions, solve) -> Result:
    """Solve ``problems`` (``stage_problems``) in turn with ``solve(problem, options)`` (``kincal.estimation.solve``,
    passed in: the solver module imports this one), each from the previous stage's final state. Returns the last
    stage's ``Result`` with the record of every stage (``Result.stages``), the residual statistics at stage 1's
    start as ``before`` and the outer iterations and evaluations of all stages."""
    results: list[Result] = []
    for i, problem in enumerate(problems):
        if results:
            problem = Problem.assemble(problem.robot, problem.experiments, problem.layout, problem.nominal,
                                       problem.noise, results[-1].state, problem.constraints, problem.unknown)
        try:
            results.append(solve(problem, replace(options, gauge=_stage_gauge(problem, options.gauge))))
        except DegenerateExperimentError as exc:
            raise DegenerateExperimentError(f"{label(stages, i)}: {exc}") from None
    records = tuple(_record(s, i, r) for i, (s, r) in enumerate(zip(stages, results)))
    last = results[-1]
    notes = (_note(problems, stages),) + tuple(
        f"{label(stages, i)} ended {r.status}; the stages after it started from its state"
        for i, r in enumerate(results[:-1]) if r.status in ("not converged", "degenerate"))
    return replace(last, before=results[0].before, stages=records, messages=notes + last.messages,
                   iterations=sum(r.iterations for r in results), evaluations=sum(r.evaluations for r in results))


def _stage_gauge(problem: Problem, gauge):
    """A gauge priority list keeps, in each stage, the patterns that match one of its free coordinates (none:
    ``min-change``)."""
    if isinstance(gauge, str):
        return gauge
    layout = problem.layout
    names = [(layout.names[i], layout.block_at(i).name) for i in problem.free_idx]
    kept = [p for p in gauge if any(fnmatch.fnmatchcase(n, p) or fnmatch.fnmatchcase(b, p) for n, b in names)]
    return kept or "min-change"


def _record(stage: Stage, i: int, result: Result) -> StageRecord:
    return StageRecord(name=stage.name or f"stage {i + 1}", free=stage.free, fixed=stage.fixed,
                       parameters=len(result.identifiability.names), rank=result.identifiability.rank,
                       cost=float(sum(s.chi2 for s in result.after)), sigma2=result.sigma2, status=result.status,
                       iterations=result.iterations, after=result.after)


def _note(problems: Sequence[Problem], stages: Sequence[Stage]) -> str:
    """What the last stage's covariance is conditional on: the coordinates an earlier stage estimated and the
    last one holds at that estimate."""
    last = problems[-1].layout
    earlier = np.zeros(last.size, bool)
    for p in problems[:-1]:
        earlier |= p.layout.free
    held = list(dict.fromkeys(last.block_at(i).name for i in np.flatnonzero(earlier & ~last.free)))
    text = (f"staged solve, {len(stages)} stage(s), each started from the state of the one before: estimates, "
            f"covariance and verdicts are those of the last stage, {label(stages, len(stages) - 1)}")
    if held:
        text += (f"; its standard deviations are conditional on {', '.join(held)}, held at the earlier stages' "
                 "estimates (their uncertainty is not carried over)")
    return text
