"""The Dask back end of ``kincal study`` and ``kincal batch``: tasks on a local cluster (``workers`` processes
with one thread each) or on an existing one (``scheduler``: its address), results in task order.

Dask is an optional dependency (``pip install kincal[study]``), imported here only. Every task runs with BLAS
held to one thread (threadpoolctl), whatever the worker's environment: workers are the parallelism. A task's
result depends on its arguments only (seeds travel with the task), so the outcome is the same on any number
of workers. ``workers=0`` runs the tasks in this process, one after another, without Dask.
"""

from __future__ import annotations

import logging
import multiprocessing
from multiprocessing import forkserver
import os
from typing import Callable, Sequence

from threadpoolctl import threadpool_limits

from kincal.errors import KincalError

DASK_HINT = "Dask is not installed: pip install 'kincal[study]' (or run with --workers 0, in this process)"


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def single_threaded(fn: Callable, *args):
    """``fn(*args)`` with BLAS on one thread."""
    with threadpool_limits(limits=1):
        return fn(*args)


def run_tasks(fn: Callable, tasks: Sequence[tuple], *, workers: int | None = None, scheduler: str | None = None,
              progress: Callable[[int], None] | None = None) -> list:
    """``[fn(*t) for t in tasks]`` on the back end; ``progress(i)`` after task ``i`` completes (any order)."""
    if scheduler is None and workers == 0:
        out = []
        for i, t in enumerate(tasks):
            out.append(single_threaded(fn, *t))
            if progress:
                progress(i)
        return out
    client, cluster = _connect(workers, scheduler)
    try:
        return _gather(client, fn, tasks, progress)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _connect(workers: int | None, scheduler: str | None):
    """(client, the local cluster it owns or None)."""
    method = None if scheduler is not None else _start_forkserver()
    try:
        import dask  # optional heavy dependency: only here
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise KincalError(DASK_HINT) from None
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as exc:
            raise KincalError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({exc})") from None
    n = default_workers() if workers is None else workers
    with dask.config.set({"distributed.worker.multiprocessing-method": method}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


# What the forkserver imports once for every local worker it forks.
PRELOAD = ["distributed", "kincal.workflow.study", "kincal.workflow.batch"]


def _start_forkserver() -> str:
    """The start method of local workers, with the forkserver started at once where there is one: it imports
    ``PRELOAD`` while this process imports Dask (on two cores, at the same time instead of one after the other).

    Workers forked from a clean server process start fast with kincal imported once, where forking this
    process itself (threads of its own, the caller's, BLAS pools) can deadlock a child on a held lock;
    spawned workers would import numpy, scipy and kincal again, seconds each."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    multiprocessing.set_forkserver_preload(PRELOAD)
    forkserver.ensure_running()
    return "forkserver"


def _gather(client, fn: Callable, tasks: Sequence[tuple], progress) -> list:
    from dask.distributed import as_completed  # optional heavy dependency: only here

    futures = [client.submit(single_threaded, fn, *t, pure=False) for t in tasks]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list = [None] * len(futures)
    for f in as_completed(futures):
        i = index[f.key]
        out[i] = f.result()
        if progress:
            progress(i)
    return out
