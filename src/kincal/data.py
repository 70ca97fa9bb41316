"""In-memory experiment data sets: what was measured, per experiment kind.

A ``Dataset`` holds joint readings per arm (model order, SI units) plus the measurements and known
transforms of its kind. Files (CSV + YAML manifest) map onto it in ``kincal.io.datasets``; ground truth
never lives here (see ``Truth`` in ``kincal.simulate``).

Kinds and their entries (N samples; shapes batch-first):

================  ====================================  ======================================================
kind              measured                              known (optional unless marked *)
================  ====================================  ======================================================
``pose``          ``T_tracker_tool`` (N, 4, 4)          ``T_world_tracker`` (4, 4)
                  ``wrench_tool`` (N, 6) optional
``markers``       ``p_tracker_marker`` (N, m, 3)        ``T_world_tracker`` (4, 4), ``p_tool_marker`` (m, 3),
                  ``wrench_tool`` (N, 6) optional
``clamp``         --                                    ``T_world_fixture`` (4, 4)
``plate``         ``fixture`` (N,) int in [0, K)        ``T_plate_fixture`` (K, 4, 4) *, ``T_world_plate`` (4, 4)
``dual``          --                                    ``T_toolA_toolB`` (4, 4): arm B's tool in arm A's tool
``socket``        --                                    ``p_world_socket`` (3,): tool point held in a socket
``distance``      --                                    ``distance`` (): |p_A - p_B| of the two arms' tool points
``plane``         --                                    ``plane_world`` (4,): n . p = d with unit n
================  ====================================  ======================================================

``wrench_tool`` (pose, markers): the load (force, torque) applied TO the tool BY the environment, tool frame,
N and N m, acting at the tool origin; it deflects compliant joints (``kincal.kinematics.elastic``).

``arms`` lists the arms involved (two for ``dual`` and ``distance``, first is A). Unknown quantities
(absent from ``known``) become parameters of the calibration.

``frames`` (optional, role -> frame name) names the frames of the data set's roles (``ROLES``: ``tracker``,
``markers``, ``fixture``, ``plate``, ``clamp``, ``socket``, ``plane``). Data sets that name the same frame share
one parameter block, e.g. two marker sessions with the same tracker: ``frames={"tracker": "lab_tracker"}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal.errors import DegenerateExperimentError, ShapeError

KINDS = {
    # kind: (number of arms, required measured keys, optional measured keys, required known keys, optional known keys)
    "pose": (1, ("T_tracker_tool",), ("wrench_tool",), (), ("T_world_tracker",)),
    "markers": (1, ("p_tracker_marker",), ("wrench_tool",), (), ("T_world_tracker", "p_tool_marker")),
    "clamp": (1, (), (), (), ("T_world_fixture",)),
    "plate": (1, ("fixture",), (), ("T_plate_fixture",), ("T_world_plate",)),
    "dual": (2, (), (), (), ("T_toolA_toolB",)),
    "socket": (1, (), (), (), ("p_world_socket",)),
    "distance": (2, (), (), ("distance",), ()),
    "plane": (1, (), (), (), ("plane_world",)),
}


# The frames each kind names: role -> its entry in ``known``. A role is what a frame is, so only frames of the same
# role can be shared (a tracker with a tracker, never with a fixture).
ROLES = {
    "pose": {"tracker": "T_world_tracker"},
    "markers": {"tracker": "T_world_tracker", "markers": "p_tool_marker"},
    "clamp": {"fixture": "T_world_fixture"},
    "plate": {"plate": "T_world_plate"},
    "dual": {"clamp": "T_toolA_toolB"},
    "socket": {"socket": "p_world_socket"},
    "distance": {},
    "plane": {"plane": "plane_world"},
}
# frame names end up in parameter names and are matched by the globs of free/fixed/priors
_NAME_FORBIDDEN = set("*?[] \t\n")


def frames_problem(kind: str, frames, arms=()) -> tuple[str, str] | None:
    """The first bad entry of a ``frames`` mapping (role -> frame name) as (field, problem), or None.

    ``arms``: the model's arm names; a frame named like an arm would give parameters named like the arm's.
    """
    if not isinstance(frames, Mapping):
        return "frames", f"expected a mapping role -> frame name, found {type(frames).__name__}"
    roles = ROLES[kind]
    for role, name in frames.items():
        where = f"frames.{role}"
        if role not in roles:
            return where, (f"expected a role of kind '{kind}' ({', '.join(roles) or 'none'}), found {role!r}")
        if not isinstance(name, str) or not name or _NAME_FORBIDDEN & set(name):
            return where, f"expected a non-empty frame name without spaces or *?[], found {name!r}"
        clash = next((a for a in arms if name == a or name.startswith(f"{a}.")), None)
        if clash is not None:
            return where, (f"expected a name that does not start with an arm of the model ('{clash}', whose "
                           f"parameters are named '{clash}.*'), found {name!r}")
    return None


def _ro(a) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Dataset:
    """One experiment's data. See the module docstring for the kinds."""

    kind: str
    robot: str
    arms: tuple[str, ...]
    q: Mapping[str, np.ndarray]
    measured: Mapping[str, np.ndarray] = field(default_factory=dict)
    known: Mapping[str, np.ndarray] = field(default_factory=dict)
    name: str = "experiment"
    meta: Mapping = field(default_factory=dict)
    frames: Mapping[str, str] = field(default_factory=dict)  # role -> frame name (shared between data sets)

    def __post_init__(self) -> None:
        where = f"data set '{self.name}'"
        if self.kind not in KINDS:
            raise ShapeError(f"{where}: unknown kind {self.kind!r}; kinds: {', '.join(KINDS)}")
        n_arms, req_m, opt_m, req_k, opt_k = KINDS[self.kind]
        arms = tuple(self.arms)
        if len(arms) != n_arms:
            raise ShapeError(f"{where}: kind '{self.kind}' needs {n_arms} arm(s), got {list(arms)}")
        object.__setattr__(self, "arms", arms)
        q = {}
        for arm in arms:
            if arm not in self.q:
                raise ShapeError(f"{where}: no joint readings for arm '{arm}'")
            qa = np.asarray(self.q[arm], dtype=float)
            if qa.ndim != 2:
                raise ShapeError(f"{where}: joint readings of arm '{arm}' must be (N, n), got shape {qa.shape}")
            bad = np.argwhere(~np.isfinite(qa))
            if len(bad):
                raise ShapeError(f"{where}: arm '{arm}' sample {bad[0][0]} joint {bad[0][1]} is {qa[tuple(bad[0])]}")
            q[arm] = _ro(qa)
        counts = {qa.shape[0] for qa in q.values()}
        if len(counts) != 1:
            raise ShapeError(f"{where}: arms have different sample counts {[(a, q[a].shape[0]) for a in arms]}")
        for key, allowed_req, allowed_opt, store in (
            ("measured", req_m, opt_m, self.measured),
            ("known", req_k, opt_k, self.known),
        ):
            for k in allowed_req:
                if k not in store:
                    raise ShapeError(f"{where}: kind '{self.kind}' needs {key} '{k}'")
            for k in store:
                if k not in allowed_req + allowed_opt:
                    raise ShapeError(
                        f"{where}: unexpected {key} entry '{k}' for kind '{self.kind}'; "
                        f"allowed: {', '.join(allowed_req + allowed_opt) or 'none'}"
                    )
        object.__setattr__(self, "q", MappingProxyType(q))
        object.__setattr__(self, "measured", MappingProxyType({k: _ro(v) for k, v in self.measured.items()}))
        object.__setattr__(self, "known", MappingProxyType({k: _ro(v) for k, v in self.known.items()}))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        bad = frames_problem(self.kind, self.frames)
        if bad:
            raise ShapeError(f"{where}: field {bad[0]}: {bad[1]}")
        object.__setattr__(self, "frames", MappingProxyType(dict(self.frames)))
        n = self.size
        for k, v in self.measured.items():
            if v.shape[:1] != (n,):
                raise ShapeError(f"{where}: measured '{k}' has {v.shape[:1]} samples, joint readings have {n}")
        w = self.measured.get("wrench_tool")
        if w is not None and w.shape != (n, 6):
            raise ShapeError(f"{where}: measured 'wrench_tool' must be (N, 6) (force, torque), got shape {w.shape}")
        if n == 0:
            raise DegenerateExperimentError(f"{where}: contains no samples")

    @property
    def size(self) -> int:
        return next(iter(self.q.values())).shape[0]

    def subset(self, index) -> "Dataset":
        """The samples selected by ``index`` (slice, mask or integer array)."""
        return Dataset(
            self.kind,
            self.robot,
            self.arms,
            {a: v[index] for a, v in self.q.items()},
            {k: v[index] for k, v in self.measured.items()},
            dict(self.known),
            self.name,
            dict(self.meta),
            dict(self.frames),
        )
