"""The memory a solve will need, estimated from the problem's size before anything large is allocated, and the
refusal when it will not fit.

The estimate is ``8 * rows * (PER_ROW + PER_CELL * free)`` bytes beyond what the process holds already, ``rows``
the residual rows (samples times residual components) and ``free`` the free coordinates. The constants were
measured (tracemalloc peak of ``calibrate`` with outliers rejected, ``Problem.build`` included, above the memory
held before; numbers are doubles per residual row):

    kind      robot   free  rows     peak/row   of which per free column
    markers   ur10      21  180000      337      1.5 (Jacobian copies alive at once)
    markers   ur10      51  180000      382
    pose      ur10      12   60000      310      0.8
    pose      ur10      42   60000      335
    dual      frida     14   24000      298      5.8 (joint noise: whitened copies)
    dual      frida     82   24000      695
    markers   ur10      12  600000      380      (peak resident size of the process, tests/test_size.py)

About 300 doubles per row are the experiments' working arrays (forward kinematics per joint, residual
Jacobians per parameter block before they are scattered into columns); the rest is the stacked Jacobian and
the copies the solver keeps of it (whitened, restricted to the identifiable subspace, least_squares' own). The
resident size also holds what the allocator keeps and BLAS buffers. The constants below bound every case
measured, with a margin of at least 20 %.

That is the peak of a problem held at once. A problem that would need more than ``BLOCKS`` blocks of
``CHUNK_BYTES`` so (``by_blocks``) is evaluated in blocks of ``chunk_rows`` rows (``estimation.blocks``): ``need_bytes`` is then one block's working memory plus ``KEPT_PER_ROW`` doubles per
row (residuals, whiteners, encoder Jacobians, statistics: measured 64 on Frida's dual arm with encoder noise by
tracemalloc, about 80 as resident size at 100,000 configurations, tests/test_scale.py and bench/bench_scale.py).

The limit is the memory available now: ``MemAvailable`` in /proc/meminfo (else the system's available pages),
and below a cgroup's ``memory.max`` when one is set; ``KINCAL_MEMORY_LIMIT`` (bytes, or with K, M, G, T)
overrides it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from kincal.errors import ResourceError
from kincal.experiments.base import KINDS

PER_ROW = 450.0
PER_CELL = 8.0
# A problem larger than one block of this many bytes of working memory is evaluated block by block
# (``estimation.blocks``); what stays of the data's size is ``KEPT_PER_ROW`` doubles per residual row (residual,
# whiteners, encoder Jacobians, statistics).
CHUNK_BYTES = 32 * 2**20
# Only a problem that would need more than this many blocks' memory held at once is evaluated by blocks: below,
# the stacked path is faster (one evaluation of the whole Jacobian serves every reader of it).
BLOCKS = 8
KEPT_PER_ROW = 120.0
ENV = "KINCAL_MEMORY_LIMIT"
# A solve needing less than this is not checked against the machine's free memory (reading /proc and the cgroup
# costs about as much as a small calibration's set-up); ``KINCAL_MEMORY_LIMIT`` is still obeyed.
UNCHECKED_BYTES = 16 * 2**20
_SUFFIX = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def solve_bytes(rows: int, free: int) -> int:
    """The peak memory (bytes) a solve with ``rows`` residual rows and ``free`` free coordinates allocates when
    it holds them all at once (one block)."""
    return int(8 * rows * (PER_ROW + PER_CELL * free))


def need_bytes(rows: int, free: int) -> int:
    """The peak memory (bytes) of the solve as it runs: ``solve_bytes`` up to one block; a larger problem holds one
    block's working memory and ``KEPT_PER_ROW`` doubles per row (``estimation.blocks``)."""
    if not by_blocks(rows, free):
        return solve_bytes(rows, free)
    return min(solve_bytes(rows, free), solve_bytes(chunk_rows(free), free) + int(8 * rows * KEPT_PER_ROW))


def by_blocks(rows: int, free: int) -> bool:
    """Whether a problem of ``rows`` residual rows and ``free`` free coordinates is evaluated by blocks: held at
    once it would need more than ``BLOCKS`` blocks' memory."""
    return solve_bytes(rows, free) > BLOCKS * CHUNK_BYTES


def chunk_rows(free: int) -> int:
    """Residual rows per block of a large problem (``estimation.blocks``): ``CHUNK_BYTES`` of working memory."""
    return max(int(CHUNK_BYTES / (8 * (PER_ROW + PER_CELL * free))), 1)


def memory_limit() -> tuple[int, str]:
    """(bytes the solve may use, where that number comes from)."""
    text = os.environ.get(ENV, "").strip()
    if text:
        m = re.fullmatch(r"([0-9]+(?:\.[0-9]*)?)\s*([KMGT]?)I?B?", text.upper())
        if m is None:
            raise ResourceError(f"{ENV}={text[:40]!r}: expected a number of bytes, optionally with K, M, G or T")
        return int(float(m.group(1)) * _SUFFIX[m.group(2)]), ENV
    limits = [(_meminfo_available(), "available RAM (/proc/meminfo)"), (_cgroup_room(), "the cgroup's memory.max")]
    limits = [(b, src) for b, src in limits if b is not None]
    return min(limits) if limits else (_sysconf_available(), "available RAM (sysconf)")


def residual_rows(datasets) -> int:
    """Residual rows of a problem over ``datasets``: samples times the residual components of their kind."""
    return sum(ds.size * len(KINDS[ds.kind](ds, {}).components()) for ds in datasets)  # no frames needed


def require_memory(datasets, free: int = 0, rows: int | None = None) -> None:
    """Raise a one-line ResourceError when the solve over ``datasets`` with ``free`` free coordinates will not fit
    in ``memory_limit()``. With ``free=0`` (before the parameter layout is known) it refuses what the data
    alone make too large. ``rows``: ``residual_rows(datasets)`` when known already."""
    rows = residual_rows(datasets) if rows is None else rows
    need = need_bytes(rows, free)
    if need < UNCHECKED_BYTES and not os.environ.get(ENV, "").strip():
        return
    limit, source = memory_limit()
    if need > limit:
        raise ResourceError(
            f"the solve needs about {_gib(need)} ({rows} residual rows x {free} free parameters) but {source} is "
            f"{_gib(limit)}: use fewer configurations or fewer free parameters (or set {ENV})")


def _gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**30 else f"{n / 2**20:.3g} MiB"


def _meminfo_available() -> int | None:
    try:
        text = Path("/proc/meminfo").read_text()
    except OSError:
        return None
    m = re.search(r"^MemAvailable:\s+([0-9]+) kB", text, re.M)
    return int(m.group(1)) * 1024 if m else None


def _cgroup_room() -> int | None:
    """memory.max - memory.current of this process' cgroup (v2), when a limit is set."""
    try:
        top = Path("/sys/fs/cgroup")
        limit, used = (top / "memory.max").read_text().strip(), (top / "memory.current").read_text().strip()
    except OSError:
        return None
    return int(limit) - int(used) if limit.isdigit() and used.isdigit() else None


def _sysconf_available() -> int:
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 2**62  # unknown: no refusal
