"""Predicted accuracy of a calibrated model at given joint readings, before anyone trusts it there.

From the tool pose's Jacobian ``J`` (N, 6, p_free) w.r.t. the result's free local coordinates (world-frame left
increment, ``kincal.kinematics.tool_jacobians``), mapped to the change ``E`` of the tool *point* and of
its orientation (world frame), per configuration:

* standard deviations: ``sqrt(trace)`` of the 3x3 position and orientation blocks of ``E C E^T`` with
  ``C = result.covariance`` (scaled by the residual variance, weak directions included): the RMS length of
  the error vector, comparable with validation RMS errors. A linearization at the estimate;
* the effect of the directions the data cannot determine (``null_space``) and of those it determines only
  from the noise (``weak_vectors``): the tool motion per unit norm of a direction in natural units (m and
  rad: "mm per mm-or-mrad"), the largest over the whole subspace.

``register=True`` first removes what one common rigid motion of all N predicted poses absorbs (least squares
in natural units): a self-calibration cannot see the world frame, and validation sets fit their tracker or
fixture too. What remains says whether the *relative* geometry of the configurations is known.
``register_tool=True`` also removes one common motion of the tool frame (the same right increment for every
configuration): what a validation set absorbs when it fits unknown marker offsets or an unknown clamp.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from kincal._validate import as_array
from kincal.errors import ModelError, ShapeError
from kincal.analysis.columns import scatter_columns
from kincal.analysis.error_budget import measurement_noise, model_error
from kincal.analysis.linalg import svd
from kincal.experiments._kernel import ARM_PARTS, point_jacobian, tree_jacobians, tree_kin
from kincal.kinematics import chain, loaded_chain, tool_jacobians
from kincal.kinematics.model import lineage
from kincal.lie import se3
from kincal.noise import Noise
from kincal.schema import BETWEEN, TOOL, WORLD, schema_of

# Tool motion (m or rad) per unit of a direction below which it does not matter here: exact gauges come out
# at round-off (~1e-12), directions that matter at 1e-3 and above.
NULL_TOL = 1e-6



@dataclass(frozen=True)
class DirectionEffect:
    """A named direction and its largest effect over the configurations, per unit norm in natural units (m and
    rad of tool motion). ``kind``: unidentifiable (``pivot`` as in ``Identifiability.directions``), scale
    (``pivot`` "scale", ``partners`` the largest lengths), or weak (``pivot``: its largest coordinate)."""

    kind: str
    pivot: str
    partners: tuple[tuple[str, float], ...]
    position: float
    orientation: float


@dataclass(frozen=True, eq=False)
class Prediction:
    arm: str
    registered: bool  # a common world-frame motion removed
    tool_registered: bool  # a common tool-frame motion removed
    position_std: np.ndarray  # (N,) m, sqrt(trace) of the tool position covariance
    orientation_std: np.ndarray  # (N,) rad, sqrt(trace) of the tool orientation covariance
    null_position: np.ndarray  # (N,) m per unit: largest over unit-norm unidentifiable directions
    null_orientation: np.ndarray  # (N,) rad per unit
    weak_position: np.ndarray  # (N,) m per unit: largest over unit-norm weakly identifiable directions
    weak_orientation: np.ndarray  # (N,) rad per unit
    null_moving: int  # independent unidentifiable directions that move the poses (effect >= NULL_TOL)
    weak_moving: int  # the same for weakly identifiable directions
    directions: tuple[DirectionEffect, ...]  # named directions that move the tool, largest effect first
    messages: tuple[str, ...]
    position_noise: np.ndarray | None = None  # (N,) m: what the measurement's stated noise adds (0: none given)
    orientation_noise: np.ndarray | None = None  # (N,) rad
    position_model: float = 0.0  # m: RMS error the calibrated model cannot represent (``error_budget``)
    orientation_model: float = 0.0  # rad; nan: unknown (no orientation measured, a model error in position)
    doubts: tuple[str, ...] = ()  # why not to trust the model besides undetermined directions (misfit, ...)

    @property
    def samples(self) -> int:
        return len(self.position_std)

    @property
    def trusted(self) -> bool:
        """No direction the data cannot determine, or determine only from the noise, moves the predicted poses,
        and nothing else (``doubts``: a model that does not explain its data, validation worse than nominal)
        speaks against the model."""
        return self.null_moving == 0 and self.weak_moving == 0 and not self.doubts

    @property
    def position_rms_predicted(self) -> float:
        """The RMS position error (m) to expect at these configurations: parameter uncertainty, the stated
        measurement noise and the model error the calibration could not explain, in quadrature."""
        return _expected(self.position_std, self.position_noise, self.position_model)

    @property
    def orientation_rms_predicted(self) -> float:
        """The same for the orientation (rad); nan (not predicted) when the model error in orientation is
        unknown: calibration data that measure no orientation and that the model does not explain say nothing
        about how wrong its orientation is, and a number from the parameters alone would be a confident low one."""
        return _expected(self.orientation_std, self.orientation_noise, self.orientation_model)

    def stats(self) -> dict:
        """RMS and max of the standard deviations, largest effects per unit, the expected RMS error and its
        parts (SI: m, rad)."""
        return {"position_std_rms": _rms(self.position_std), "position_std_max": _max(self.position_std),
                "orientation_std_rms": _rms(self.orientation_std), "orientation_std_max": _max(self.orientation_std),
                "null_position_max": _max(self.null_position), "null_orientation_max": _max(self.null_orientation),
                "weak_position_max": _max(self.weak_position), "weak_orientation_max": _max(self.weak_orientation),
                "position_rms_predicted": self.position_rms_predicted,
                "orientation_rms_predicted": self.orientation_rms_predicted,
                "position_noise_rms": _rms(_zeros(self.position_noise, self.samples)),
                "orientation_noise_rms": _rms(_zeros(self.orientation_noise, self.samples)),
                "position_model": self.position_model, "orientation_model": self.orientation_model}


def tool_jacobian(result, q, arm: str, with_jq: bool = False, wrench: np.ndarray | None = None):
    """Calibrated ``T_world_tool`` (N, 4, 4) at joint readings q (N, n) and its Jacobian (N, 6, p_free): the
    world-frame left increment per free local coordinate of ``result`` (columns in ``result.covariance``
    order; experiment frames get zero columns); ``with_jq``: also the one w.r.t. the joint readings (N, 6, n).
    ``wrench`` (N, 6): the loads on the tool (tool frame, as data's ``wrench_tool``), which deflect compliant
    joints as in the experiments: the compliances then move the tool (None: unloaded, they do not).
    A mounted arm (``Robot.mounts``) takes ``q`` as a mapping arm -> readings over its lineage; its Jacobian
    covers the carriers' blocks, and the readings' one their joints too (lineage order)."""
    a = _arm_values(result, arm)
    if len(lineage(result.state.mounts, arm)) > 1:
        return _tree_tool_jacobian(result, q, arm, with_jq, wrench)
    q = _joints(q, a, arm)
    if wrench is None:
        kin = chain(a.screws, q + a.offsets, a.base, a.home, a.tool)
    else:
        wrench = _loads(wrench, len(q), arm)
        kin = loaded_chain(a.screws, q + a.offsets, a.base, a.home, a.tool, a.compliance_at(q), wrench,
                           coupling=a.coupling)
    blocks, jq = tool_jacobians(kin, np.broadcast_to(np.eye(6), (len(q), 6, 6)), a.screws, a.generators,
                                a.joint_compliance, with_jq=with_jq, basis=a.compliance_basis(q))
    layout = result.layout
    J = scatter_columns({f"{arm}.{part}": Jb for part, Jb in blocks.items()}, layout, np.flatnonzero(layout.free),
                        (len(q), 6))
    return (kin.tool, J, jq) if with_jq else (kin.tool, J)


def _tree_tool_jacobian(result, q, arm: str, with_jq: bool, wrench=None):
    line = lineage(result.state.mounts, arm)
    if not isinstance(q, dict) or any(s not in q for s in line):
        raise ShapeError(f"q: arm '{arm}' is mounted on {', '.join(line[:-1])}: expected readings of {', '.join(line)}")
    q = {s: _joints(q[s], result.state.arms[s], s) if s in line else np.asarray(v, float) for s, v in q.items()
         if s in result.state.arms}  # other arms' readings: their weight loads the carriers (gravity on a tree)
    kin = tree_kin(result.state, line, q, None if wrench is None else _loads(wrench, len(q[arm]), arm))
    blocks, jqs = {}, {}
    tree_jacobians(result.state, line, q, kin, np.broadcast_to(np.eye(6), (len(q[arm]), 6, 6)),
                   {s: ARM_PARTS for s in q}, with_jq, blocks, jqs)
    J = scatter_columns(blocks, result.layout, np.flatnonzero(result.layout.free), (len(q[arm]), 6))
    return (kin.tool, J, np.concatenate([jqs[s] for s in line], axis=-1)) if with_jq else (kin.tool, J)


def predicted_accuracy(result, q, arm: str, *, register: bool = True, register_tool: bool = False,
                       noise: Noise | None = None, wrench: np.ndarray | None = None) -> Prediction:
    """Predicted standard deviations of the tool pose at q (N, n), its dependence on unidentifiable and weakly
    identifiable directions (module docstring), and the RMS error to expect there (``position_rms_predicted``):
    with the stated measurement ``noise`` of data taken there (None: the model's own error only) and the model
    error the calibration could not explain. ``wrench`` (N, 6): the loads there (tool frame; ``tool_jacobian``):
    the compliances' uncertainty then counts. Registration needs 2 configurations (it absorbs one whole)."""
    T, J, Jq = tool_jacobian(result, q, arm, with_jq=True, wrench=wrench)
    if (register or register_tool) and len(T) < 2:
        raise ShapeError(f"q: registration needs at least 2 configurations (a common rigid motion absorbs any "
                         f"change of one pose), found {len(T)}; pass register=False for world-frame predictions")
    P = _point_map(T[:, :3, 3])
    common = [P] if register else []
    if register_tool:
        common.append(P @ se3.adjoint(T))  # a right increment g of T is the left increment Ad(T) g
    E = _unregistered_part(P @ J, np.concatenate(common, axis=-1)) if common else P @ J  # (N, 6, p)
    var = np.sum((E @ result.covariance) * E, axis=-1).clip(0)  # diagonal of E C E^T, (N, 6)
    ana = result.identifiability
    W = ana.weak_vectors if ana.weak_vectors is not None else np.zeros((len(ana.names), 0))
    Dn, Dw = E @ ana.null_space, E @ W
    effects = [DirectionEffect(kind, pivot, partners, _max(np.linalg.norm(E[:, :3] @ v, axis=-1)),
                               _max(np.linalg.norm(E[:, 3:] @ v, axis=-1)))
               for kind, pivot, partners, v in _named_directions(ana, W, _arm_coordinates(result))]
    effects = sorted((e for e in effects if max(e.position, e.orientation) >= NULL_TOL),
                     key=lambda e: (-e.position, -e.orientation))
    pos_noise, rot_noise = measurement_noise(P @ Jq, noise)
    pos_model, rot_model = model_error(result)
    pred = Prediction(arm, register, register_tool, np.sqrt(var[:, :3].sum(-1)), np.sqrt(var[:, 3:].sum(-1)),
                      _spectral(Dn[:, :3]), _spectral(Dn[:, 3:]), _spectral(Dw[:, :3]), _spectral(Dw[:, 3:]),
                      _moving(Dn), _moving(Dw), tuple(effects), (), pos_noise, rot_noise,
                      pos_model, rot_model, _doubts(result))
    return replace(pred, messages=_messages(pred, result))


def with_doubts(pred: Prediction, doubts) -> Prediction:
    """``pred`` with further reasons not to trust the model (e.g. found by validation), its messages rewritten."""
    if not doubts:
        return pred
    return replace(pred, doubts=pred.doubts + tuple(doubts),
                   messages=pred.messages + tuple(f"the calibrated model should not be trusted: {d}" for d in doubts))


# Actual validation RMS this many times the predicted: the prediction does not hold there (the band the real data
# sets keep is [0.67, 1.5]; beyond 2 the model error measured at the calibration configurations does not carry).
UNDERSTATED_RATIO = 2.0
# Errors below this (m, rad; the whitening's floor for unstated noise) are round-off: no prediction to hold.
ROUNDOFF = 1e-9


def understated(pred: Prediction, set_name: str, position: float | None, orientation: float | None) -> list[str]:
    """Why ``pred`` is not to be relied on at a validation set whose actual RMS errors (m, rad; None: not
    measured) exceed ``UNDERSTATED_RATIO`` times the predicted (and ``ROUNDOFF``): the model error measured where
    the calibration data were taken does not carry to these configurations."""
    out = []
    for part, actual, predicted, scale, unit in (
            ("position", position, pred.position_rms_predicted, 1e3, "mm"),
            ("orientation", orientation, pred.orientation_rms_predicted, 180 / np.pi, "deg")):
        if actual is not None and np.isfinite(predicted) and actual > max(UNDERSTATED_RATIO * predicted, ROUNDOFF):
            times = actual / predicted if predicted > 0 else np.inf
            out.append(f"on '{set_name}' the actual {part} error ({actual * scale:.3g} {unit} RMS) is "
                       f"{times:.3g} times the predicted ({predicted * scale:.3g} {unit}): the model "
                       "error seen at the calibration configurations does not carry to these, so the predicted "
                       f"{part} error is not to be relied on")
    return out


def _doubts(result) -> tuple[str, ...]:
    """What the calibration itself says against trusting its model anywhere."""
    if result.status == "misfit":
        return (f"the model does not explain its calibration data (status misfit, residual variance factor "
                f"{result.sigma2:.3g}): expect the unexplained model error everywhere",)
    if result.status in ("degenerate", "not converged"):
        return (f"the calibration is {result.status}",)
    return ()


def validation_predictions(result, datasets, noise=()) -> tuple[tuple[str, Prediction], ...]:
    """(data set name, prediction) for every calibrated arm of every data set, registered as the validation fits
    the data set's frames: the world side unless it is given, the tool side when it is not given (marker offsets,
    a dual-arm clamp). Per arm: a two-arm set's relative error is only approximated. ``noise``: the stated
    noise of each data set (in order; none: the model's own error only). A data set's loads (``wrench_tool``)
    deflect the predicted chain as they deflect the measured one."""
    out = []
    noise = tuple(noise) or (None,) * len(datasets)
    for ds, nz in zip(datasets, noise):
        # a given world-side frame: compared in the world frame, else fitted; tool-side frames fitted unless given
        schema = schema_of(ds.kind)
        world, tool = schema.side_key(WORLD), schema.side_key(TOOL, BETWEEN)
        register = world is None or world not in ds.known
        register_tool = tool is not None and tool not in ds.known
        if (register or register_tool) and ds.size < 2:
            continue  # fitting its frame absorbs a single pose whole: nothing to predict or validate
        for arm in ds.arms:
            if arm in result.state.arms:  # an arm the calibration did not involve was not estimated
                q = dict(ds.q) if arm in result.state.mounts else ds.q[arm]  # a mounted arm: with its carriers'
                out.append((ds.name, predicted_accuracy(result, q, arm, register=register,
                                                        register_tool=register_tool, noise=nz,
                                                        wrench=ds.measured.get("wrench_tool"))))
    return tuple(out)


def _arm_values(result, arm):
    arms = result.state.arms
    if not isinstance(arm, str) or arm not in arms:
        raise ModelError(f"arm: expected one of the calibrated arms ({', '.join(arms)}), found {arm!r}")
    return arms[arm]


def _joints(q, a, arm) -> np.ndarray:
    if np.ndim(q) != 2 or np.shape(q)[1] != a.dof or len(q) == 0:
        raise ShapeError(f"q: expected joint readings of shape (N, {a.dof}) with N >= 1 for arm '{arm}' "
                         f"({', '.join(a.joint_names)}), found shape {np.shape(q)}")
    return as_array(q, "q", (a.dof,))


def _loads(wrench, n: int, arm: str) -> np.ndarray:
    if np.shape(wrench) != (n, 6):
        raise ShapeError(f"wrench: expected the loads on arm '{arm}' at each configuration, shape ({n}, 6) "
                         f"(force, torque in the tool frame), found shape {np.shape(wrench)}")
    return as_array(wrench, "wrench", (6,))


def _point_map(p: np.ndarray) -> np.ndarray:
    """(N, 6, 6): left increment -> (tool point displacement, rotation), both in the world frame."""
    P = np.zeros((len(p), 6, 6))
    P[:, :3] = point_jacobian(p)
    P[:, 3:, 3:] = np.eye(3)
    return P


def _unregistered_part(E: np.ndarray, P: np.ndarray) -> np.ndarray:
    """E (N, 6, c) minus its least-squares fit by the common motions whose effect per pose is P (N, 6, r)."""
    N, _, c = E.shape
    Q = np.linalg.qr(P.reshape(6 * N, P.shape[-1]))[0]
    flat = E.reshape(6 * N, c)
    return (flat - Q @ (Q.T @ flat)).reshape(N, 6, c)


def _spectral(D: np.ndarray) -> np.ndarray:
    """Largest singular value per configuration of D (N, 3, k): worst unit-norm combination; 0 when k = 0."""
    return svd(D, compute_uv=False)[:, 0] if D.shape[-1] else np.zeros(len(D))


def _moving(D: np.ndarray) -> int:
    """How many independent directions of D (N, 6, k) move the poses: singular values of the stack >= NULL_TOL."""
    if D.shape[-1] == 0:
        return 0
    return int(np.sum(svd(D.reshape(-1, D.shape[-1]), compute_uv=False) >= NULL_TOL))


def _arm_coordinates(result) -> np.ndarray:
    """(p_free,) bool: free coordinates of arm parameters (not experiment frames)."""
    arm = np.zeros(result.layout.size, bool)
    for b in result.layout.blocks:
        arm[b.start: b.stop] = b.arm is not None
    return arm[result.layout.free]


def _named_directions(ana, W, arm):
    """(kind, pivot, partners, unit vector): the reported null directions, scale when it is unidentifiable (the
    reported ones leave it out: it is the rest of the null space), and the weak ones (pivot: the largest arm
    parameter, what measurements can excite)."""
    out = [("unidentifiable", d.pivot, d.partners, d.vector / np.linalg.norm(d.vector)) for d in ana.directions]
    if ana.scale_unidentifiable:
        V = np.stack([v for *_, v in out], axis=-1) if out else np.zeros((len(ana.names), 0))
        Q = np.linalg.qr(V)[0]
        s = svd(ana.null_space - Q @ (Q.T @ ana.null_space), full_matrices=False)[0][:, 0]
        top, rest = _by_size(s, ana.names, arm)
        out.append(("scale", "scale", ((top, 1.0),) + rest, s))
    out += [("weak", *_by_size(w, ana.names, arm), w) for w in W.T]
    return out


def _by_size(v, names, arm, count: int = 5):
    """The largest arm coordinate's name, and the next largest coordinates with coefficients relative to it."""
    a = np.abs(v)
    piv = int(np.argmax(np.where(arm, a, -1.0))) if arm.any() else int(np.argmax(a))
    rest = [i for i in np.argsort(-a) if i != piv and a[i] > 1e-3 * a[piv]][:count]
    return names[piv], tuple((names[i], float(v[i] / v[piv])) for i in rest)


def _messages(pred: Prediction, result) -> tuple[str, ...]:
    ana = result.identifiability
    st = pred.stats()
    after = {(True, False): " after registration", (True, True): " after registration of the world and tool frames",
             (False, True): " after registration of the tool frame"}.get((pred.registered, pred.tool_registered), "")
    out = [(f"at the {pred.samples} configurations of arm '{pred.arm}' the predicted tool position is uncertain by "
            f"{st['position_std_rms'] * 1e3:.3g} mm RMS (max {st['position_std_max'] * 1e3:.3g} mm) and its "
            f"orientation by {np.degrees(st['orientation_std_rms']):.3g} deg RMS "
            f"(max {np.degrees(st['orientation_std_max']):.3g} deg){after}, one standard deviation")]
    rot = (f"{np.degrees(pred.orientation_rms_predicted):.3g} deg" if np.isfinite(pred.orientation_rms_predicted)
           else "an unknown orientation error (the calibration data measure no orientation and the model does not "
                "explain their positions)")
    out.append(f"expect errors of {pred.position_rms_predicted * 1e3:.3g} mm and {rot} RMS there: the standard "
               f"deviations, the stated measurement noise ({st['position_noise_rms'] * 1e3:.3g} mm, "
               f"{np.degrees(st['orientation_noise_rms']):.3g} deg) and the model error the calibration could not "
               f"explain ({pred.position_model * 1e3:.3g} mm, {np.degrees(pred.orientation_model):.3g} deg) together")
    if result.status == "degenerate":
        out.append("the calibration is degenerate: nothing was estimated, these figures mean nothing")
    out += [f"the calibrated model should not be trusted: {d}" for d in pred.doubts]
    k = ana.null_space.shape[1]
    if k and not pred.null_moving:
        out.append(f"the {k} direction(s) the data cannot determine do not move the predicted tool poses{after} "
                   f"(at most {st['null_position_max']:.2g} mm per mm-or-mrad): exact gauges here")
    elif pred.null_moving:
        out.append(f"{pred.null_moving} of the {k} direction(s) the data cannot determine move the predicted tool by "
                   f"up to {st['null_position_max']:.3g} mm and {st['null_orientation_max']:.3g} mrad per mm-or-mrad "
                   f"along them{after}: they are held at nominal, so the prediction is off by however far the "
                   "robot is from nominal along them")
    if pred.weak_moving:
        out.append(f"{pred.weak_moving} weakly identifiable direction(s), estimated from little more than the noise, "
                   f"move the predicted tool by up to {st['weak_position_max']:.3g} mm and "
                   f"{st['weak_orientation_max']:.3g} mrad per mm-or-mrad along them{after}: the standard deviations "
                   "above linearize at an estimate that wanders along them and can understate the error many times "
                   "over")
    if not pred.trusted and pred.directions:
        d = pred.directions[0]
        arm = dict(zip(ana.names, _arm_coordinates(result)))
        names = [n for n, _ in d.partners if arm.get(n)][:3]
        partners = f" (with {', '.join(names)})" if names else ""
        todo = ("fix or measure one length: scale cannot be identified" if d.kind == "scale"
                else f"measure configurations that excite {d.pivot}{partners}")
        out.append(f"the calibrated model should not be trusted at these configurations; {todo}")
    return tuple(out)


def _expected(std: np.ndarray, noise: np.ndarray | None, model: float) -> float:
    return float(np.sqrt(np.mean(std**2 + _zeros(noise, len(std)) ** 2) + model**2)) if len(std) else 0.0


def _zeros(x: np.ndarray | None, n: int) -> np.ndarray:
    return np.zeros(n) if x is None else x


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if len(x) else 0.0


def _max(x: np.ndarray) -> float:
    return float(np.max(x, initial=0.0))


def tool_motion(result, q, arm: str, delta: np.ndarray, *, register: bool = True) -> np.ndarray:
    """(N, 6) (or (N, 6, h) for h columns of ``delta``): the tool point's displacement and the tool's rotation
    (world frame, m and rad) at q (N, n) when the free coordinates of ``result`` move by ``delta`` (p_free,) or
    (p_free, h), to first order; ``register``: with the
    common rigid motion of all N poses removed, as ``predicted_accuracy`` does."""
    T, J = tool_jacobian(result, q, arm)
    P = _point_map(T[:, :3, 3])
    E = P @ J
    if register:
        E = _unregistered_part(E, P)
    return E @ np.asarray(delta, float)
