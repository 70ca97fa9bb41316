"""Stack experiment residuals over the free coordinates and whiten them by each experiment's stated noise.

Whitening (per configuration, k x k): ``Sigma = diag(sigma_meas^2) + sum_arms sigma_joint^2 J_q J_q^T``,
``r_w = L^-1 r`` with ``Sigma = L L^T``. Encoder noise thus enters through the residual's Jacobian w.r.t. the
joint readings (first order). ``Sigma`` is evaluated at the linearization point of each outer iteration and
held during the inner solve. Measurement variances have a floor of (1e-9)^2 so a purely encoder-noise
closed chain stays positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from kincal.analysis.columns import scatter_columns
from kincal.estimation.constraints import constraint_rows
from kincal.errors import ModelError
from kincal.experiments import Experiment
from kincal.noise import ORIENTATION, POSITION, Noise
from kincal.params import Layout, State, displacement, pose_retraction_jacobians, retract

VARIANCE_FLOOR = 1e-18


@dataclass(frozen=True, eq=False)
class Problem:
    experiments: Sequence[Experiment]
    layout: Layout
    nominal: State  # the reference: priors, reported changes, the gauge's "minimum change"
    noise: Sequence[Noise]
    start: State | None = None  # where the solve starts (default: nominal)
    constraints: Sequence = ()  # FrameDistance rows (estimation.constraints)

    def __post_init__(self):
        if self.start is None:
            object.__setattr__(self, "start", self.nominal)
        free = np.flatnonzero(self.layout.free)
        object.__setattr__(self, "free_idx", free)
        prior = np.isfinite(self.layout.prior_sigma) & self.layout.free
        object.__setattr__(self, "prior_idx", np.flatnonzero(prior))
        want = {b.name for b in self.layout.blocks if self.layout.free[b.start: b.stop].any()}
        object.__setattr__(self, "want", want)
        object.__setattr__(self, "_plain", (None, None))  # (state, residuals without Jacobians) of the last call

    @property
    def joint_noise(self) -> bool:
        """Whether any experiment states encoder noise (whitening then depends on the state through J_q)."""
        return any(nz.joint_sigma() > 0 for nz in self.noise)

    def _residuals(self, state: State):
        """Residuals (with ``jq`` when encoder noise is stated, no parameter Jacobians) at ``state``; whitening and
        statistics ask for the same state in turn, so the last one is kept (states are immutable)."""
        cached_state, res = self._plain
        if cached_state is not state:
            res = [exp.residual(state, want=set(), jq=self.joint_noise) for exp in self.experiments]
            object.__setattr__(self, "_plain", (state, res))
        return res

    @property
    def free_names(self) -> list[str]:
        return [self.layout.names[i] for i in self.free_idx]

    def equations(self) -> list[int]:
        return [e.size * len(e.components()) for e in self.experiments]

    def full_delta(self, delta_free: np.ndarray) -> np.ndarray:
        d = np.zeros(self.layout.size)
        d[self.free_idx] = delta_free
        return d

    def whiteners(self, state: State) -> list[np.ndarray]:
        """Per experiment (N, k, k) inverse Cholesky factors of the residual covariance at ``state``."""
        return self._whiteners_of(self._residuals(state))

    def _whiteners_of(self, residuals) -> list[np.ndarray]:
        out = []
        for exp, nz, res in zip(self.experiments, self.noise, residuals):
            var = np.maximum(stated_sigmas(exp, nz) ** 2, VARIANCE_FLOOR)
            sj = nz.joint_sigma()
            if sj > 0:
                cov = np.broadcast_to(np.diag(var), res.r.shape + (res.r.shape[1],)).copy()
                for jq in res.jq.values():
                    cov += sj**2 * (jq @ np.swapaxes(jq, -1, -2))
                out.append(np.linalg.inv(np.linalg.cholesky(cov)))
            else:  # constant: a diagonal, broadcast over samples
                out.append(np.broadcast_to(np.diag(1.0 / np.sqrt(var)), res.r.shape + (res.r.shape[1],)))
        return out

    def linearize(self, state: State, whiteners=None, cols=None):
        """Whitened residual (m,) and Jacobian at ``state`` in one evaluation of the experiments.

        ``cols``: layout indices of the Jacobian's columns (default: the free coordinates; the scale test adds
        fixed ones). ``whiteners=None``: whiten at ``state`` from the same evaluation's ``J_q``.
        Returns ``(r, J, whiteners)``.
        """
        cols = self.free_idx if cols is None else np.asarray(cols)
        want = {b.name for b in self.layout.blocks if np.any((cols >= b.start) & (cols < b.stop))}
        fresh = whiteners is None
        res = [exp.residual(state, want=want, jq=fresh and self.joint_noise) for exp in self.experiments]
        W = self._whiteners_of(res) if fresh else whiteners
        if fresh or not self.joint_noise:  # statistics at this state need no second evaluation
            object.__setattr__(self, "_plain", (state, res))
        r, J = self._stack(state, res, W, cols, {})
        return r, J, W

    def length_part(self, state: State, whiteners) -> np.ndarray:
        """The whitened stacked residual with only its length components kept (prior rows zero).

        Where no measured length enters a loop (clamp, dual, socket, plane, distance with lengths all free),
        scaling every length by ``1 + e`` changes the residual by exactly ``e`` times this, to first order:
        the scale test compares it with the Jacobian's scale column."""
        out = []
        for exp, W, res in zip(self.experiments, whiteners, self._residuals(state)):
            keep = np.array([c.length for c in exp.components()], float)
            out.append((W @ (res.r * keep)[:, :, None]).ravel())
        if len(self.prior_idx):
            out.append(np.zeros(len(self.prior_idx)))
        out.append(np.zeros(len(self.constraints)))  # a known distance does not scale with the robot
        return np.concatenate(out)

    def evaluate(self, state0: State, delta_free: np.ndarray, whiteners, jac: bool = True):
        """Whitened stacked residual (m,) at ``retract(state0, delta)`` and, if asked, its Jacobian (m, p_free)."""
        delta = self.full_delta(delta_free)
        state = retract(state0, self.layout, delta)
        if not jac:
            res = [exp.residual(state, want=set(), jq=False) for exp in self.experiments]
            return self._stack(state, res, whiteners, None, {})[0], None
        Rl = {k: v for k, v in pose_retraction_jacobians(self.layout, delta).items() if k in self.want}
        res = [exp.residual(state, want=self.want, jq=False) for exp in self.experiments]
        return self._stack(state, res, whiteners, self.free_idx, Rl)

    def _stack(self, state, residuals, whiteners, cols, Rl):
        """Whiten and stack residuals and (``cols`` not None) the Jacobian columns ``cols`` of the layout;
        ``Rl``: retraction Jacobians of pose blocks stepped away from their linearization point."""
        rs, Js = [], []
        for res, W in zip(residuals, whiteners):
            rs.append((W @ res.r[:, :, None]).ravel())
            if cols is None:
                continue
            N, k = res.r.shape
            J = scatter_columns(res.jac, self.layout, cols, (N, k), Rl)
            Js.append((W @ J).reshape(N * k, -1))
        if len(self.prior_idx):
            disp, D = displacement(state, self.nominal, self.layout)
            sig = self.layout.prior_sigma[self.prior_idx]
            rs.append((disp[self.prior_idx] - self.layout.prior_mean[self.prior_idx]) / sig)
            if cols is not None:
                Dfull = D[self.prior_idx]
                for name, Jl in Rl.items():
                    b = self.layout.block(name)
                    Dfull[:, b.start: b.stop] = Dfull[:, b.start: b.stop] @ Jl
                Js.append(Dfull[:, cols] / sig[:, None])
        if len(self.constraints):
            rc, Jc = constraint_rows(self.constraints, state, self.layout, Rl, cols)
            rs.append(rc)
            if cols is not None:
                Js.append(Jc)
        r = np.concatenate(rs)
        return (r, np.concatenate(Js, axis=0)) if cols is not None else (r, None)

    def statistics(self, state: State, whiteners=None) -> list[dict]:
        """Per experiment: samples, position / orientation RMS and max (norm per sample), whitened chi^2."""
        W = self.whiteners(state) if whiteners is None else whiteners
        out = []
        for exp, Wi, res in zip(self.experiments, W, self._residuals(state)):
            r = res.r
            comp = exp.components()
            st = {"experiment": exp.name, "kind": exp.kind, "samples": exp.size}
            st.update(residual_norms(r, comp))
            st["chi2"] = float(np.sum(np.einsum("nij,nj->ni", Wi, r) ** 2))
            st["dof"] = int(r.size)
            out.append(st)
        return out


def stated_sigmas(exp: Experiment, noise: Noise) -> np.ndarray:
    """Per residual component of ``exp``, the standard deviation ``noise`` states for its quantity."""
    out = []
    for q in exp.components():
        sigma = noise.sigma(q)
        if sigma is None:
            raise ModelError(
                f"data set '{exp.name}' ({exp.kind}) has {q.name} residuals ({q.unit}) but the stated noise gives no "
                f"{q.name} standard deviation; state it (Noise({q.name}=...) or noise: {{{q.name}_<unit>: ...}})")
        out.append(sigma)
    return np.array(out, dtype=float)


def residual_norms(r: np.ndarray, components) -> dict:
    """RMS and max over samples of the position-part and orientation-part norms (m, rad)."""
    st = {}
    for key, q in (("position", POSITION), ("orientation", ORIENTATION)):
        mask = np.array([c == q for c in components], bool)
        if mask.any():
            if mask.sum() % 3 == 0 and key == "position" and mask.sum() > 1:
                e = np.linalg.norm(r[:, mask].reshape(len(r), -1, 3), axis=-1).ravel()
            elif key == "orientation":
                e = np.linalg.norm(r[:, mask], axis=-1)
            else:
                e = np.abs(r[:, mask]).ravel()
            st[f"{key}_rms"] = float(np.sqrt(np.mean(e**2)))
            st[f"{key}_max"] = float(np.max(e))
    return st
