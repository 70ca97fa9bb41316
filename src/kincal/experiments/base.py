"""The experiment interface: a pure residual of one data set with its analytic Jacobian.

An experiment reads every value it needs from a ``State``: arm parameters by arm name, and its frames
(fixture pose, clamp transform, tracker frame, ...) from ``state.extras`` under the names in ``frames``.
Known frames are extras too (fixed unless the user frees them), so one code path serves known and unknown.
"""

from __future__ import annotations

import hashlib

import weakref
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import ClassVar, Mapping

import numpy as np

from kincal._memo import remember
from kincal.data import Dataset
from kincal.experiments._kernel import ARM_PARTS, arm_jacobians, coupled, tree_jacobians, tree_kin
from kincal.kinematics import Kinematics, loaded_chain, sample_chain
from kincal.kinematics.fk import paired_shifted_turns
from kincal.kinematics.branches import loading_branches
from kincal.kinematics.model import lineage, same_array_bits
from kincal.noise import Quantity
from kincal.params import State
from kincal.schema import NONE, Field, Schema, register

# Every registered experiment class by kind (filled as the kind modules are imported: ``kincal.experiments``).
KINDS: dict[str, type["Experiment"]] = {}

# The optional load on the tool (force, torque; N, N m; tool frame), a measured entry of tracker kinds.
WRENCH = Field("wrench_tool", "vector", NONE, required=False, size=6,
               columns=("wrench.fx", "wrench.fy", "wrench.fz", "wrench.tx", "wrench.ty", "wrench.tz"),
               doc="the load applied TO the tool BY the environment, tool frame, acting at the tool origin")


@dataclass(frozen=True)
class Residual:
    """``r`` (N, k); ``jac[block]`` (N, k, d) for parameter blocks (``right.offsets``, ``fixture``, ...);
    ``jq[arm]`` (N, k, n): derivative w.r.t. the joint readings, for propagating encoder noise (empty when
    not asked for)."""

    r: np.ndarray
    jac: Mapping[str, np.ndarray]
    jq: Mapping[str, np.ndarray]


# The (arm, wanted blocks) pairs an experiment keeps the parts of (``Experiment._parts``): a solve asks for two or
# three sets of blocks (the scale test's columns, the free ones).
PARTS_ENTRIES = 8

# Experiment -> {arm: (geometry, Kinematics)}: the last kinematics of each arm while a solve remembers them
# (``remembered_kinematics``); weak keys, so an experiment no longer used takes its entry with it.
_KINEMATICS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()

# The fields of ``ArmValues`` the kinematics do not read: the tangent bases and generators of the twists (a
# trial point retracts without them, ``params.retract(tangents=False)``, its Jacobian evaluation with them).
_TANGENT_FIELDS = frozenset({"bases", "generators"})


@contextmanager
def remembered_kinematics(experiments, on: bool = True):
    """Within the block, ``experiments`` keep their last kinematics per arm and reuse them at a state of the same
    geometry (every arm's field but the tangent bases equal bit for bit, and the same mounts): a trial point
    accepted by the inner solver is then not evaluated twice (its residual, then its Jacobian). ``on`` False:
    nothing kept (a problem solved by blocks keeps no state of the data's size)."""
    mine = [e for e in experiments if on and e not in _KINEMATICS]
    for e in mine:
        _KINEMATICS[e] = {}
    try:
        yield
    finally:
        for e in mine:
            _KINEMATICS.pop(e, None)


def _geometry(state: State) -> tuple:
    """What the kinematics of any arm of ``state`` are computed from: the mounts and every arm's values."""
    return tuple(state.mounts.items()), tuple(state.arms.items())


def _same_geometry(a: tuple, b: tuple) -> bool:
    """Bit for bit the same geometry (``_geometry``): the same arms, each the same object or with every field
    but the tangent ones equal in type, shape and bytes."""
    if a[0] != b[0] or len(a[1]) != len(b[1]):
        return False
    return all(ka == kb and (va is vb or _same_values(va, vb)) for (ka, va), (kb, vb) in zip(a[1], b[1]))


def _same_values(a, b) -> bool:
    for name in _compared_fields(type(a)):
        x, y = getattr(a, name), getattr(b, name)
        if x is not y and not same_bits(x, y):  # a retraction keeps the fields it does not move: the same objects
            return False
    return True


# Per values class, the names of the fields ``_same_values`` compares (its fields but the tangent ones), in order:
# the class's own declaration, read once (``dataclasses.fields`` builds its tuple at every call).
_COMPARED: dict[type, tuple[str, ...]] = {}


def _compared_fields(cls: type) -> tuple[str, ...]:
    names = _COMPARED.get(cls)
    if names is None:
        names = _COMPARED[cls] = tuple(f.name for f in fields(cls) if f.name not in _TANGENT_FIELDS)
    return names


def same_bits(x, y) -> bool:
    """Equal bit for bit (arrays, and tuples of them), or the same object."""
    if x is y:
        return True
    if isinstance(x, np.ndarray) and isinstance(y, np.ndarray):
        return same_array_bits(x, y)
    if isinstance(x, tuple) and isinstance(y, tuple):
        return len(x) == len(y) and all(same_bits(u, v) for u, v in zip(x, y))
    return isinstance(x, (str, int, float)) and type(x) is type(y) and x == y


@dataclass(frozen=True, eq=False)
class Experiment:
    """Base class; a kind sets SCHEMA (its data, ``kincal.schema``) and COMPONENTS. Defining the subclass
    registers its schema with the data layer and the class in ``KINDS``; KIND and ROLES (role -> key in
    ``dataset.known``) are read off the schema."""

    dataset: Dataset
    frames: Mapping[str, str]  # role -> name of the state extra holding it

    SCHEMA: ClassVar[Schema | None] = None
    KIND: ClassVar[str] = ""
    ROLES: ClassVar[Mapping[str, str]] = {}
    COMPONENTS: ClassVar[tuple[Quantity, ...]] = ()
    # The residual is a vector in world coordinates, which turns when the world does (a socket point); the
    # others are written in a frame that turns along, or are scalars (identifiability's rotation test).
    WORLD_VECTOR: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if cls.SCHEMA is None:
            raise TypeError(f"{cls.__name__}: an experiment kind declares its SCHEMA")
        register(cls.SCHEMA)
        cls.KIND = cls.SCHEMA.kind
        cls.ROLES = cls.SCHEMA.role_keys
        KINDS[cls.KIND] = cls

    @property
    def name(self) -> str:
        return self.dataset.name

    @property
    def kind_name(self) -> str:
        return self.KIND

    @property
    def kind(self) -> str:
        return self.KIND

    @property
    def arms(self) -> tuple[str, ...]:
        return self.dataset.arms

    @property
    def size(self) -> int:
        return self.dataset.size

    def components(self) -> tuple[Quantity, ...]:
        """Per residual column, the quantity it measures (``kincal.noise``): whitening reads its stated noise."""
        return self.COMPONENTS

    def residual(self, state: State, want=None, jq: bool = True) -> Residual:
        """Residual at ``state``; Jacobians of the blocks in ``want`` (None: every block), and ``jq`` if asked."""
        raise NotImplementedError

    def initial(self, state: State, known: Mapping[str, object]) -> dict[str, object]:
        """Initial values for the roles absent from ``known``, from the state's (nominal) arms."""
        raise NotImplementedError

    def check(self) -> None:
        """Raise on data this kind cannot use (beyond what Dataset checks)."""

    def covariance(self) -> np.ndarray | None:
        """The residual's covariance per sample (N, k, k) when the data state it (a pose's ``pose_cov``), else
        None: whitening then uses the stated noise per component (``estimation.problem``)."""
        return None

    def noise_covariance(self) -> np.ndarray | None:
        """The residual's actual covariance per sample (N, k, k) where the fit weights by another (``covariance``
        or the stated noise: a reweighted pose's ``noise_cov``), else None (the fit weights by the noise)."""
        return None

    def frame_shape(self, role: str) -> tuple[int, ...]:
        """Shape of the value of a role's frame, to check data sets sharing it agree: the schema's shape, with
        data-chosen sizes (markers ``m``) read off this data set."""
        return self.frame_shapes()[role]

    def frame_shapes(self) -> dict[str, tuple[int, ...]]:
        """``frame_shape`` of every role, the data's sizes read once."""
        d = self.dataset
        sizes = self.SCHEMA.sizes(d.measured, d.known, d.size)
        return {role: tuple(sizes.get(s, -1) if isinstance(s, str) else s for s in self.SCHEMA.field(key).shape)
                for role, key in self.ROLES.items()}

    def start(self, nominal: State, free_parts, unknown) -> dict[str, np.ndarray]:
        """Corrections of tool frames before solving (``{"<arm>.tool": X}``: start from ``tool @ X``) when this
        data can tell that the nominal tool is too far off for the solver's local steps; none by default.
        ``free_parts``: the free arm poses (``"<arm>.tool"``, ``"<arm>.home"``) of the data set's arms not
        corrected yet; ``unknown``: the names of the unknown frames."""
        return {}

    def increment_frames(self, state: State) -> dict[str, np.ndarray]:
        """World pose of the frame in which each pose role's left increment is expressed (first sample)."""
        return {role: np.eye(4) for role in self.frames}

    # helpers
    def _parts(self, arm: str, want) -> tuple[str, ...]:
        """The parts of ``arm`` whose blocks ``want`` names (all for None); kept per (arm, want) when ``want`` is a
        frozenset (a problem's, the same at every linearization of a solve): its hash is its own, kept by Python."""
        if not isinstance(want, frozenset):
            return tuple(p for p in ARM_PARTS if want is None or f"{arm}.{p}" in want)
        kept = self.__dict__.setdefault("_wanted_parts", {})  # a frozen dataclass: its own dict, no attribute
        hit = kept.get((arm, want))
        if hit is None:
            hit = remember(kept, (arm, want), tuple(p for p in ARM_PARTS if f"{arm}.{p}" in want), PARTS_ENTRIES)
        return hit

    @staticmethod
    def _residual_only(want, jq: bool) -> bool:
        """No Jacobian asked for (a trial point's evaluation): the residual alone."""
        return want is not None and not want and not jq

    def _wanted(self, role: str, want) -> bool:
        return role in self.frames and (want is None or self.frames[role] in want)

    def _kin(self, state: State, arm: str) -> Kinematics:
        """The arm's kinematics at the data's readings (the composite chain through its ancestors when mounted,
        ``kincal.kinematics.tree``); deflected by ``wrench_tool`` when the data has loads and by the arm's own
        weight when its model has masses and gravity (``kincal.kinematics.gravity``; on a tree the weights of all
        its arms, ``kincal.kinematics.branches``). While kinematics are remembered (``remembered_kinematics``)
        the last ones per arm are reused at a state of the same geometry, bit for bit."""
        memo = _KINEMATICS.get(self)
        if memo is None:
            return self._fresh_kin(state, arm)
        key = _geometry(state)
        last = memo.get(arm)
        if last is not None and _same_geometry(last[0], key):
            return last[1]
        kin = self._fresh_kin(state, arm)
        memo[arm] = (key, kin)
        return kin

    def _fresh_kin(self, state: State, arm: str) -> Kinematics:
        """``_kin`` computed."""
        line = lineage(state.mounts, arm)
        if len(line) > 1 or hung_arms(state, line) or state.arms[arm].lateral is not None:
            return tree_kin(state, line, self.dataset.q, self.dataset.measured.get("wrench_tool"))
        a = state.arms[arm]
        theta0 = self.dataset.q[arm] + a.offsets
        w = self.dataset.measured.get("wrench_tool")
        if w is None and a.weights is None:
            return sample_chain(a.screws, theta0, a.base, a.home, a.tool, self._turns(arm, a.offsets))
        c = a.compliance_at(self.dataset.q[arm])  # (n,), or (N, n) when a joint's compliance depends on its angle
        return loaded_chain(a.screws, theta0, a.base, a.home, a.tool, c, w, a.weights, coupling=a.coupling)

    def _turns(self, arm: str, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(cos, sin)`` of the arm's readings plus ``offsets`` (``fk.paired_shifted_turns``) from the readings'
        own, kept stacked per arm with a digest of the readings' bytes: data, not state (the same at every evaluation
        of a solve); the digest, so that readings changed in place miss without a copy of them kept per arm."""
        q = self.dataset.q[arm]
        kept = self.__dict__.setdefault("_reading_turns", {})  # a frozen dataclass: its own dict, no attribute
        key = _digest(q)
        hit = kept.get(arm)
        if hit is None or hit[0] != key:
            hit = kept[arm] = (key, np.stack([np.cos(q), np.sin(q)]))
        return paired_shifted_turns(hit[1], offsets)

    def _fk(self, state: State, arm: str) -> np.ndarray:
        return self._kin(state, arm).tool

    def _arm_jac(self, state: State, arm: str, kin: Kinematics, G: np.ndarray, want, jq: bool, out: dict,
                 jqs: dict) -> None:
        """Add ``{arm.part: G @ J_part}`` to ``out`` and ``G @ J_q`` to ``jqs[arm]`` (if asked); G (N, k, 6) is
        the residual's derivative w.r.t. the left increment of ``T_world_tool``. A mounted arm adds its
        ancestors' blocks and readings too (added to what another arm of the data set put there)."""
        line = lineage(state.mounts, arm)
        hung = hung_arms(state, line)
        if len(line) > 1 or hung or state.arms[arm].lateral is not None:  # lateral: the composite's expanded chain
            parts = {s: self._parts(s, want) for s in (*line, *hung)}
            if any(parts.values()) or jq:
                tree_jacobians(state, line, self.dataset.q, kin, G, parts, jq, out, jqs)
            return
        parts = self._parts(arm, want)
        if not parts and not jq:
            return
        blocks, gq = arm_jacobians(state.arms[arm], kin, G, parts, with_jq=jq, q=self.dataset.q[arm])
        out.update({f"{arm}.{p}": J for p, J in blocks.items()})
        if jq:
            jqs[arm] = coupled(state.arms[arm], gq)


def hung_arms(state: State, line) -> list[str]:
    """The other arms whose weight loads the joints of ``line`` (``kincal.kinematics.branches``)."""
    if not state.mounts:
        return []
    return loading_branches(state.mounts, {a: v.weights for a, v in state.arms.items()}, line)


def _digest(a: np.ndarray) -> bytes:
    """A 16-byte digest of an array's bytes (BLAKE2b), with its shape and dtype."""
    h = hashlib.blake2b(str((a.shape, a.dtype.str)).encode(), digest_size=16)
    h.update(np.ascontiguousarray(a).data)
    return h.digest()
