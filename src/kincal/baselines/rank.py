"""The thesis' Jacobian analysis (Table 4.10): rank of its identification Jacobian for one arm measured by the
other (full pose of the flange), with the null vectors named in the thesis' terms.

Thesis names: ``dq_i`` for joint i's offset, ``dv_{i,k}`` and ``dw_{i,k}`` for the k-th linear and angular
coordinate of twist i (unnormalized, 6 per joint), ``dxi_st,k`` for the home twist. kincal's own analysis
(``kincal.estimation.plan``) uses its minimal parametrization instead; this module reproduces the thesis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.baselines.identification import identification_jacobian
from kincal.kinematics import ArmModel

# Singular values below this fraction of the largest are zero (exact dependencies sit at round-off).
RANK_RTOL = 1e-9


@dataclass(frozen=True)
class RankRow:
    """One row of Table 4.10: the blocks, the Jacobian's shape, its rank and the full rank, and each null vector
    as (thesis name, coefficient) pairs, largest first, normalized to the first coefficient 1."""

    blocks: tuple[str, ...]
    shape: tuple[int, int]
    rank: int
    full: int
    null_vectors: tuple[tuple[tuple[str, float], ...], ...]

    @property
    def deficiency(self) -> int:
        return self.full - self.rank


def thesis_names(model: ArmModel, blocks) -> list[str]:
    """Column names of the thesis' Jacobian for ``blocks`` in kincal's column order, in the thesis' terms."""
    out = []
    for b in blocks:
        if b == "twists":
            out += [f"d{'v' if k < 3 else 'w'}{i + 1},{k % 3 + 1}" for i in range(model.dof) for k in range(6)]
        elif b == "offsets":
            out += [f"dq{i + 1}" for i in range(model.dof)]
        else:
            out += [f"dxi_{'st' if b == 'home' else b},{k + 1}" for k in range(6)]
    return out


def thesis_rank(model: ArmModel, q: np.ndarray, blocks=("twists", "home"), tol: float = 1e-6) -> RankRow:
    """Rank of the thesis' identification Jacobian (6N, columns of ``blocks``) at joint readings q (N, n), and
    its null vectors (entries below ``tol`` of the largest left out)."""
    J, _ = identification_jacobian(model, q).stacked(tuple(blocks))
    J = J.reshape(-1, J.shape[-1])
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    rank = int(np.sum(s > RANK_RTOL * s[0]))
    names = thesis_names(model, blocks)
    vectors = []
    for v in Vt[rank:]:
        order = np.argsort(-np.abs(v))
        lead = v[order[0]]
        vectors.append(tuple((names[i], float(v[i] / lead)) for i in order if abs(v[i]) > tol * abs(lead)))
    return RankRow(tuple(blocks), J.shape, rank, J.shape[1], tuple(vectors))
