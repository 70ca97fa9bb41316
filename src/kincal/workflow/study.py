"""Monte Carlo studies of a calibration (``kincal study``, docs/partial-pose.md): a true robot, an experiment and
its noise, repeated; every repeat calibrated by each variant; per variant and quantity the bias, standard
deviation and RMS of the estimates, what the calibration reported as its standard deviation next to the
empirical one, and the distribution of the validation error.

Seeds: everything drawn once (the true robot, fixed configurations, the validation configurations) comes from
``SeedSequence(seed, spawn_key=(0, i))``, repeat ``r`` from ``SeedSequence(seed, spawn_key=(1, r))``: the table
depends on the seed only, never on how repeats are spread over workers (``kincal.workflow.parallel``).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, Mapping

import numpy as np

from kincal.data import Dataset
from kincal.errors import DataFormatError, KincalError
from kincal.estimation import Problem, SolverOptions, calibrate, solve
from kincal.estimation.outliers import any_beyond, outlier_threshold
from kincal.experiments.pose import weighted
from kincal.experiments.pose_from_markers import markers_to_pose
from kincal.io import units
from kincal.io.atomic import output_directory
from kincal.io.studies import load_study, write_csv
from kincal.kinematics import Robot, forward_kinematics
from kincal.noise import NONE, Noise
from kincal.params import State, build_layout, displacement
from kincal.report.study_plots import write_study_plots
from kincal.schema import schema_of
from kincal.simulate import GENERATORS, perturb_robot, random_configurations
from kincal.simulate.noise import joint_readings, tracker_points, tracker_poses
from kincal.simulate.perturb import Perturbation, perturbation, with_errors
from kincal.workflow.parallel import default_workers, run_tasks

FAILED = "failed"


@dataclass(frozen=True)
class Variant:
    """One way to calibrate every repeat: ``data`` (``markers`` as measured, or ``pose`` computed from them),
    ``weighting`` of pose data (``full``: the fitted pose's 6x6 covariance; ``diagonal``; ``equal``: 1 m = 1 rad,
    ``length_per_radian`` sets the normalization) and ``options``, keywords of ``kincal.estimation.calibrate`` (``free``, ``fixed``, ``gauge``, ...).
    ``noise_known``: a ``diagonal`` or ``equal`` fit knows the fitted pose's covariance and reports the
    sandwich (honest); false: the std its weights imply, as the paper reports approach 1."""

    name: str
    data: str = "markers"
    weighting: str = "full"
    options: Mapping[str, Any] = field(default_factory=dict)
    length_per_radian: float = 1.0  # ``equal`` weighting: this many metres weigh as one radian
    noise_known: bool = True


@dataclass(frozen=True, eq=False)
class Study:
    """A Monte Carlo study in SI units (``load`` reads a study file). ``errors``: explicit errors of the true
    robot by parameter name (else ``perturbation`` draws it; ``redraw``: anew every repeat). ``quantities``:
    reported linear combinations of parameters (default: every free arm parameter of each variant)."""

    name: str
    robot: Robot
    kind: str
    options: Mapping[str, Any]
    variants: tuple[Variant, ...]
    repeats: int = 100
    seed: int = 0
    noise: Noise = field(default_factory=Noise)
    configurations: str = "fixed"
    errors: Mapping[str, float] = field(default_factory=dict)
    perturbation: Perturbation | None = None
    perturb_arms: tuple[str, ...] | None = None
    redraw: bool = False
    n_validation: int = 100
    quantities: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    length_unit: str = "m"
    angle_unit: str = "rad"
    file: str = "<study>"


def load(path) -> Study:
    """The study of a study file (or a built-in study's name), checked as far as it can be before running."""
    spec = load_study(path)
    truth, u = spec["truth"], spec["units"]
    names = dict(zip(*_arm_coordinates(spec["robot"])))
    errors = truth["errors"]  # SI, names checked (kincal.io.datasets.truth_errors)
    for q, terms in spec["quantities"].items():
        bad = [t for t in terms if t not in names]
        if bad:
            raise DataFormatError(f"{spec['file']}: quantities.{q}.{bad[0]}: no such parameter of '{spec['model']}'")
        if len({names[t] for t in terms}) > 1:
            raise DataFormatError(f"{spec['file']}: quantities.{q}: mixes units ({', '.join(names[t] for t in terms)})")
    accepted = set(inspect.signature(calibrate).parameters)
    for i, v in enumerate(spec["variants"]):
        for key in set(v["options"]) - accepted:
            raise DataFormatError(f"{spec['file']}: variants[{i}].{key}: this kincal's calibrate has no option "
                                  f"{key!r}")
    variants = tuple(Variant(v["name"], v["data"], v["weighting"], v["options"], v["length_per_radian"],
                             v["noise_known"]) for v in spec["variants"])
    return Study(spec["name"], spec["robot"], spec["kind"], spec["options"], variants, spec["repeats"], spec["seed"],
                 spec["noise"], spec["configurations"], errors,
                 None if errors else perturbation(truth["level"], **truth["overrides"]),
                 tuple(truth["arms"]) if truth.get("arms") else None, truth["redraw"], spec["validation"],
                 spec["quantities"], u["length"], u["angle"], spec["file"])


def _arm_coordinates(robot: Robot):
    layout = build_layout(State.from_robot(robot), [])
    return layout.names, layout.units


# --------------------------------------------------------------------------------------------- one repeat


@dataclass(frozen=True, eq=False)
class Fixed:
    """What every repeat shares: the true robot (unless redrawn), the seed of fixed configurations and the
    validation configurations (per arm)."""

    true: Robot | None
    experiment_seed: np.random.SeedSequence
    q_validation: Mapping[str, np.ndarray]
    memo: dict = field(default_factory=dict, repr=False)  # per process: what a fixed truth, a structure makes once

    def __reduce__(self):  # the memo stays in its process: a worker fills its own (it is cheaper than sending)
        return Fixed, (self.true, self.experiment_seed, self.q_validation)


def fixed_parts(study: Study) -> Fixed:
    truth_seed, experiment_seed, validation_seed = (np.random.SeedSequence(study.seed, spawn_key=(0, i))
                                                    for i in range(3))
    true = None if study.redraw else true_robot(study, np.random.default_rng(truth_seed))
    rng = np.random.default_rng(validation_seed)
    qv = {a: random_configurations(m, study.n_validation, rng) for a, m in study.robot.arms.items()}
    return Fixed(true, experiment_seed, qv)


def true_robot(study: Study, rng: np.random.Generator) -> Robot:
    """The study's true robot: the nominal one moved by the explicit errors, else a drawn perturbation."""
    if not study.errors:
        return perturb_robot(study.robot, study.perturbation, rng, arms=study.perturb_arms)
    return with_errors(study.robot, study.errors)


def repeat_data(study: Study, true: Robot, fixed: Fixed, rng: np.random.Generator) -> Dataset:
    """One repeat's data set: the fixed configurations with fresh noise, or everything drawn anew."""
    gen = GENERATORS[study.kind]
    if study.configurations == "redrawn":
        return gen(true, rng=rng, noise=study.noise, n_validation=1, **study.options)[0]
    exact = fixed.memo.get("exact") if true is fixed.true else None
    if exact is None:
        exact = gen(true, rng=np.random.default_rng(fixed.experiment_seed), noise=NONE, n_validation=1,
                    **study.options)[0]
        if true is fixed.true:
            fixed.memo["exact"] = exact
    return with_noise(exact, study.noise, rng)


def with_noise(ds: Dataset, noise: Noise, rng: np.random.Generator) -> Dataset:
    """``ds`` (noise-free) with the tracker and encoder noise a generator adds: positions and poses measured,
    joint readings."""
    q = {a: joint_readings(ds.q[a], noise, rng) for a in ds.arms}
    measured = dict(ds.measured)
    for f in schema_of(ds.kind).measured:
        if f.form == "points" or f.form == "point":
            measured[f.key] = tracker_points(ds.measured[f.key], noise, rng)
        elif f.form == "pose":
            measured[f.key] = tracker_poses(ds.measured[f.key], noise, rng)
    return replace(ds, q=q, measured=measured, meta={**ds.meta, "noise": noise.as_si()})


def calibrate_variant(study: Study, variant: Variant, ds: Dataset, memo: dict | None = None):
    """The ``Result`` of one variant on one repeat's data: ``calibrate``'s. With ``memo`` (a ``Fixed.memo``) a
    variant of plain options (``PLAIN_OPTIONS``) reuses the problem of its last repeat (``_calibrate_plain``)."""
    data, noise = ds, calibration_noise(study)
    if variant.data == "pose":
        data, noise = pose_data(ds, noise, variant.weighting, variant.length_per_radian, variant.noise_known)
    if memo is None or not set(variant.options) <= PLAIN_OPTIONS:
        return calibrate(study.robot, [data], noise=noise, **variant.options)
    return _calibrate_plain(study.robot, variant, data, noise, memo)


# ``calibrate``'s keywords a problem of the same structure serves: the solver's options, ``free``, ``fixed`` and
# ``outliers``. Other options (stages, priors, cv, ...) go through ``calibrate`` as given.
_SOLVER_OPTIONS = frozenset(f.name for f in fields(SolverOptions)) - {"progress"}
PLAIN_OPTIONS = _SOLVER_OPTIONS | {"free", "fixed", "outliers"}


def _calibrate_plain(robot: Robot, variant: Variant, data: Dataset, noise: Noise, memo: dict):
    """``calibrate(robot, [data], noise=noise, **variant.options)``, bit for bit, with the problem of the
    variant's last repeat given these data's measurements (``Problem.with_measurements``: the same robot object,
    options and noise, and data of the same structure), else built as ``calibrate`` builds it. A solve with rows
    beyond the outlier rule goes through ``calibrate`` itself (its robust pass and refit)."""
    opts = variant.options
    threshold = outlier_threshold(opts.get("outliers", "reject"))
    options = SolverOptions(**{k: v for k, v in opts.items() if k in _SOLVER_OPTIONS})
    key = ("problem", variant.name)
    last = memo.get(key)
    problem = None
    if last is not None and last[0] is robot and last[1] == variant and last[2] == noise:
        problem = last[3].with_measurements([data])
    if problem is None:
        free = opts.get("free")
        problem = Problem.build(robot, [data], "offsets" if free is None else free, opts.get("fixed", ()),
                                noise=noise)
        if len(problem.free_idx) == 0:  # calibrate's own error
            return calibrate(robot, [data], noise=noise, **opts)
        memo[key] = (robot, variant, noise, problem)
    result = solve(problem, options)
    if threshold is not None and any_beyond(result.problem, result.state, threshold):
        return calibrate(robot, [data], noise=noise, **opts)
    return result


def pose_data(ds: Dataset, noise: Noise, weighting: str, length_per_radian: float = 1.0,
              noise_known: bool = True) -> tuple[Dataset, Noise]:
    """Approach 1: the pose fitted to each row's markers (``markers_to_pose``), weighted as
    ``kincal.experiments.pose.weighted`` says: ``full`` (its 6x6 covariance), ``diagonal`` (without the
    correlations) or ``equal`` (the paper's: no covariance, an orientation error of 1 rad weighs as
    ``length_per_radian`` metres of position error, 1 m = 1 rad by default); ``noise_known``: the fit keeps
    the covariance for its reported std (``weighted``'s ``keep_noise``)."""
    pose = weighted(markers_to_pose(ds, sigma=noise.position), weighting, noise.position, keep_noise=noise_known)
    if weighting == "equal":
        noise = replace(noise, orientation=noise.position / length_per_radian)
    return pose, noise


def calibration_noise(study: Study) -> Noise:
    """The noise the calibrations state: the simulated one. Encoder noise the study does not state is not
    simulated, so it is zero here too (not ``kincal.noise.DEFAULT``'s, which would overstate the std)."""
    return study.noise.over(Noise(joint=0.0, backlash=0.0))


@dataclass(frozen=True)
class Outcome:
    """One variant on one repeat: ``status`` (the calibration's, or ``failed`` with ``message``), the quantities'
    ``names``, ``estimate``, ``truth`` and reported ``std`` (SI), and the validation RMS position error."""

    status: str
    names: tuple[str, ...] = ()
    estimate: np.ndarray | None = None
    truth: np.ndarray | None = None
    std: np.ndarray | None = None
    validation: float = float("nan")
    message: str = ""


def run_repeat(study: Study, fixed: Fixed, r: int) -> list[Outcome]:
    """Repeat ``r``: its data (and true robot, if redrawn) from its own seed, then every variant."""
    truth_seed, data_seed = np.random.SeedSequence(study.seed, spawn_key=(1, r)).spawn(2)
    true = fixed.true if fixed.true is not None else true_robot(study, np.random.default_rng(truth_seed))
    ds = repeat_data(study, true, fixed, np.random.default_rng(data_seed))
    out = []
    for v in study.variants:
        try:
            result = calibrate_variant(study, v, ds, fixed.memo)
        except KincalError as exc:
            out.append(Outcome(FAILED, message=str(exc)))
            continue
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:  # one bad draw, not the whole study
            out.append(Outcome(FAILED, message=f"{type(exc).__name__}: {exc}"))
            continue
        out.append(_outcome(study, result, true, fixed))
    return out


def run_chunk(study: Study, fixed: Fixed, repeats: range) -> list[list[Outcome]]:
    return [run_repeat(study, fixed, r) for r in repeats]


def _outcome(study: Study, result, true: Robot, fixed: Fixed) -> Outcome:
    layout = result.layout
    key = ("quantities", layout.names, layout.free.tobytes())  # per structure: the same rows for every repeat
    if key not in fixed.memo:
        fixed.memo[key] = quantity_matrix(study, layout)
    names, C = fixed.memo[key]
    est = np.zeros(layout.size)  # coordinates not free stay nominal: no displacement
    est[layout.free] = [e.value - e.nominal for e in result.estimates]
    key = ("truth", layout.names)
    truth = fixed.memo.get(key) if true is fixed.true else None
    if truth is None:
        truth = true_displacement(result, true)
        if true is fixed.true:
            fixed.memo[key] = truth
    Cf = C[:, layout.free]
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", Cf, result.covariance, Cf), 0.0))
    return Outcome(result.status, names, C @ est, C @ truth, std, validation_error(result.robot, true, fixed))


def true_displacement(result, true: Robot) -> np.ndarray:
    """The true robot's displacement from nominal in the result's coordinates (frames: nominal, none)."""
    nominal, true_arms = result.problem.nominal, State.from_robot(true).arms
    return displacement(nominal.replace(arms={a: true_arms[a] for a in nominal.arms}), nominal, result.layout,
                        jacobian=False)[0]


def quantity_matrix(study: Study, layout) -> tuple[tuple[str, ...], np.ndarray]:
    """The reported quantities as rows over the layout's coordinates (default: each free arm coordinate)."""
    combos = study.quantities or {layout.names[i]: {layout.names[i]: 1.0} for i in np.flatnonzero(layout.free)
                                  if layout.block_at(i).arm is not None}
    C = np.zeros((len(combos), layout.size))
    for k, terms in enumerate(combos.values()):
        for name, coef in terms.items():
            C[k, layout.index(name)] = coef
    return tuple(combos), C


def validation_error(calibrated: Robot, true: Robot, fixed: Fixed) -> float:
    """RMS distance between the calibrated and the true tool positions at the validation configurations (every
    arm), in the world frame."""
    sq = [np.sum((forward_kinematics(calibrated.arms[a], q)[:, :3, 3] - _true_tools(true, fixed, a)) ** 2, axis=1)
          for a, q in fixed.q_validation.items() if len(q)]
    return float(np.sqrt(np.mean(np.concatenate(sq)))) if sq else float("nan")


def _true_tools(true: Robot, fixed: Fixed, arm: str) -> np.ndarray:
    """The true robot's tool positions at ``arm``'s validation configurations; once per process for a fixed
    truth (``Fixed.memo``), at every repeat for a redrawn one."""
    key = ("validation tools", arm)
    if true is not fixed.true or key not in fixed.memo:
        tools = forward_kinematics(true.arms[arm], fixed.q_validation[arm])[:, :3, 3]
        if true is not fixed.true:
            return tools
        fixed.memo[key] = tools
    return fixed.memo[key]


# --------------------------------------------------------------------------------------------- the study


@dataclass(frozen=True)
class Row:
    """One variant and quantity of the table (SI; ``unit`` "m" or "rad")."""

    variant: str
    quantity: str
    unit: str
    truth: float
    bias: float
    std: float
    rms: float
    reported_std: float
    ratio: float
    used: int


@dataclass(frozen=True)
class ValidationRow:
    """A variant's validation RMS position error over the repeats (m), and its repeats used / not converged."""

    variant: str
    mean: float
    median: float
    p95: float
    max: float
    used: int
    not_converged: int
    failed: int
    first_failure: str = ""


@dataclass(frozen=True, eq=False)
class StudyResult:
    study: Study
    rows: tuple[Row, ...]
    validation: tuple[ValidationRow, ...]
    outcomes: tuple[tuple[Outcome, ...], ...]  # per repeat, per variant


# Repeats per Dask task by default: long enough that a task's cost on the back end (a few ms) stays small beside
# it; the last tasks are shorter (``TAIL_REPEATS``), so no worker (or this process, which runs tasks while the
# local cluster starts) is left running one long task alone at the end.
REPEATS_PER_TASK = 25
TAIL_REPEATS = 5


def run_study(study: Study, *, workers: int | None = None, scheduler: str | None = None, chunks: int | None = None,
              progress: Callable[[int, int], None] | None = None) -> StudyResult:
    """Run ``study``'s repeats on the Dask back end (``kincal.workflow.parallel``: ``workers`` local processes,
    0 for this process, or the cluster at ``scheduler``), in ``chunks`` tasks of equal size (default: at most
    ``REPEATS_PER_TASK`` repeats each, the last ones shorter: ``task_bounds``); ``progress(done, total)`` counts
    repeats. The study and its fixed parts go to each worker once (``run_tasks``'s ``shared``)."""
    fixed = fixed_parts(study)
    w = workers if workers is not None else (default_workers() if scheduler is None else 4)
    if chunks:
        bounds = np.linspace(0, study.repeats, min(chunks, study.repeats) + 1).astype(int)
    else:
        bounds = task_bounds(study.repeats, max(1, w) + 1)
    tasks = [(range(a, b),) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    done = [0]

    def tick(i):
        done[0] += len(tasks[i][0])
        if progress:
            progress(done[0], study.repeats)

    parts = run_tasks(run_chunk, tasks, workers=workers, scheduler=scheduler, progress=tick, shared=(study, fixed))
    outcomes = tuple(tuple(o) for part in parts for o in part)
    return summarize(study, outcomes)


def task_bounds(repeats: int, lanes: int) -> np.ndarray:
    """Task boundaries over ``repeats``: tasks of ``REPEATS_PER_TASK``, then the last ``2 * lanes`` tasks of
    ``TAIL_REPEATS`` (``lanes``: the processes that run tasks)."""
    tail = min(repeats, 2 * lanes * TAIL_REPEATS)
    head = repeats - tail
    edges = [np.linspace(0, head, -(-head // REPEATS_PER_TASK) + 1),
             np.linspace(head, repeats, -(-tail // TAIL_REPEATS) + 1)]
    return np.unique(np.concatenate(edges).astype(int))


def summarize(study: Study, outcomes) -> StudyResult:
    rows, vals = [], []
    for k, v in enumerate(study.variants):
        mine = [rep[k] for rep in outcomes]
        used = [o for o in mine if o.status == "converged"]
        rows += _rows(v.name, used, study)
        vals.append(_validation_row(v.name, mine, used))
    return StudyResult(study, tuple(rows), tuple(vals), tuple(outcomes))


def _rows(variant: str, used: list[Outcome], study: Study) -> list[Row]:
    if len(used) < 2:
        return []
    est = np.array([o.estimate for o in used])
    err = est - np.array([o.truth for o in used])
    rep = np.array([o.std for o in used])
    bias, std = err.mean(axis=0), err.std(axis=0, ddof=1)
    rms, reported = np.sqrt(np.mean(err**2, axis=0)), np.sqrt(np.mean(rep**2, axis=0))
    units_of = dict(zip(*_arm_coordinates(study.robot)))
    out = []
    for i, name in enumerate(used[0].names):
        terms = study.quantities.get(name, {name: 1.0})
        unit = units_of.get(next(iter(terms)), "")
        out.append(Row(variant, name, unit, float(np.mean(est[:, i] - err[:, i])), float(bias[i]),
                       float(std[i]), float(rms[i]), float(reported[i]),
                       float(reported[i] / std[i]) if std[i] > 0 else float("nan"), len(used)))
    return out


def _validation_row(variant: str, mine: list[Outcome], used: list[Outcome]) -> ValidationRow:
    v = np.array([o.validation for o in used if np.isfinite(o.validation)])
    stats = (float(v.mean()), float(np.median(v)), float(np.percentile(v, 95)), float(v.max())) if len(v) else (
        float("nan"),) * 4
    failed = [o for o in mine if o.status == FAILED]
    return ValidationRow(variant, *stats, len(used), len(mine) - len(used) - len(failed), len(failed),
                         failed[0].message if failed else "")


# --------------------------------------------------------------------------------------------- outputs

STUDY_ENTRIES = ("study.csv", "validation.csv", "repeats.csv")


def _scale(study: Study, unit: str) -> tuple[float, str]:
    """(divisor, unit name) of a SI unit in the study's units."""
    if unit == "m":
        return units.LENGTH[study.length_unit], study.length_unit
    if unit == "rad":
        return units.ANGLE[study.angle_unit], study.angle_unit
    return 1.0, unit


def table(result: StudyResult) -> list[dict]:
    """The study table in the study's units: per variant and quantity."""
    out = []
    for r in result.rows:
        f, u = _scale(result.study, r.unit)
        out.append({"variant": r.variant, "quantity": r.quantity, "unit": u, "truth": r.truth / f, "bias": r.bias / f,
                    "std": r.std / f, "rms": r.rms / f, "reported_std": r.reported_std / f, "ratio": r.ratio,
                    "repeats": r.used})
    return out


def validation_table(result: StudyResult) -> list[dict]:
    """Per variant: the validation RMS position error over the repeats (study length unit), and the counts."""
    f, u = _scale(result.study, "m")
    return [{"variant": v.variant, "unit": u, "mean": v.mean / f, "median": v.median / f, "p95": v.p95 / f,
             "max": v.max / f, "repeats": v.used, "not_converged": v.not_converged, "failed": v.failed,
             "first_failure": v.first_failure} for v in result.validation]


def repeats_table(result: StudyResult) -> list[dict]:
    """Every repeat and variant: status, each quantity's estimate and reported std (study units), validation."""
    out, study = [], result.study
    fv, _ = _scale(study, "m")
    for r, rep in enumerate(result.outcomes):
        for v, o in zip(study.variants, rep):
            row = {"repeat": r, "variant": v.name, "status": o.status, "validation_rms": o.validation / fv}
            for k, name in enumerate(o.names):
                f, _ = _scale(study, next((x.unit for x in result.rows if x.quantity == name), ""))
                row[f"{name}"], row[f"{name}.std"] = float(o.estimate[k]) / f, float(o.std[k]) / f
            out.append(row)
    return out


def write_study(result: StudyResult, output, *, overwrite: bool = False, plots: bool = False) -> list:
    """The study's tables as CSV in ``output`` and with ``plots`` its PNG plots in ``output/plots`` (all or
    nothing, ``kincal.io.atomic``); returns the final paths."""
    names = STUDY_ENTRIES + (("plots",) if plots else ())
    with output_directory(output, names=names, overwrite=overwrite) as stage:
        paths = [write_csv(stage.path / "study.csv", table(result)),
                 write_csv(stage.path / "validation.csv", validation_table(result)),
                 write_csv(stage.path / "repeats.csv", repeats_table(result))]
        if plots:
            paths += write_study_plots(*_plot_data(result), stage.path / "plots")
    return [stage.final(p) for p in paths]


def _plot_data(result: StudyResult):
    """Errors and reported std per quantity and variant, validation errors per variant, units: study units."""
    study, errors, reported, units_of = result.study, {}, {}, {}
    for r in result.rows:
        f, u = _scale(study, r.unit)
        k = [v.name for v in study.variants].index(r.variant)
        used = [rep[k] for rep in result.outcomes if rep[k].status == "converged"]
        i = used[0].names.index(r.quantity)
        errors.setdefault(r.quantity, {})[r.variant] = np.array([(o.estimate[i] - o.truth[i]) / f for o in used])
        reported.setdefault(r.quantity, {})[r.variant] = r.reported_std / f
        units_of[r.quantity] = u
    fv, uv = _scale(study, "m")
    validation = {v.name: np.array([rep[k].validation / fv for rep in result.outcomes
                                    if rep[k].status == "converged" and np.isfinite(rep[k].validation)])
                  for k, v in enumerate(study.variants)}
    return errors, reported, validation, {**units_of, "validation": uv}
