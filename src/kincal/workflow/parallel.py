"""The Dask back end of ``kincal study`` and ``kincal batch``: tasks on a local cluster (``workers`` processes
with one thread each) or on an existing one (``scheduler``: its address), results in task order.

Dask is an optional dependency (``pip install kincal[study]``), imported here only. Every task runs with BLAS
held to one thread (threadpoolctl), whatever the worker's environment: workers are the parallelism. A task's
result depends on its arguments only (seeds travel with the task), so the outcome is the same on any number
of workers, and whichever process runs it. ``workers=0`` runs the tasks in this process, one after another,
without Dask.

A local cluster takes seconds to start (its workers import NumPy, SciPy, kincal and Dask, then register with
the scheduler), time this process would spend waiting: it runs tasks itself meanwhile, and hands the ones
not yet begun to the workers the moment they are ready (``_Lanes``).
"""

from __future__ import annotations

import logging
import multiprocessing
from multiprocessing import forkserver
import os
import threading
import time
from collections import deque
from typing import Callable, Sequence

from threadpoolctl import threadpool_limits

from kincal.errors import KincalError

log = logging.getLogger(__name__)

DASK_HINT = "Dask is not installed: pip install 'kincal[study]' (or run with --workers 0, in this process)"


# Whether this process runs tasks while its local cluster starts (tests turn it off to have workers run all).
HERE_WHILE_STARTING = True


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def single_threaded(fn: Callable, *args):
    """``fn(*args)`` with BLAS on one thread."""
    with threadpool_limits(limits=1):
        return fn(*args)


def run_tasks(fn: Callable, tasks: Sequence[tuple], *, workers: int | None = None, scheduler: str | None = None,
              progress: Callable[[int], None] | None = None, shared: tuple = ()) -> list:
    """``[fn(*shared, *t) for t in tasks]`` on the back end; ``progress(i)`` after task ``i`` completes (any
    order). ``shared``: arguments every task takes, sent to each worker once (Dask's scatter) rather than with
    every task; a worker's tasks get the same objects, so what they remember (a study's ``Fixed.memo``) serves
    all of them."""
    if not tasks:
        return []
    if scheduler is None and workers == 0:
        out = []
        for i, t in enumerate(tasks):
            out.append(single_threaded(fn, *shared, *t))
            if progress:
                progress(i)
        return out
    lanes = _Lanes(fn, tasks, shared, progress)
    if scheduler is not None:
        client, cluster = _connect(workers, scheduler, fn)
    else:
        lanes.start_local(workers)
        try:
            if HERE_WHILE_STARTING:
                lanes.run_here()
        except BaseException:
            lanes.abandon()
            raise
        client, cluster = lanes.join()
    try:
        if scheduler is not None:  # an existing cluster is up: every task to it at once
            lanes.hand_over(client)
        return lanes.gather()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class _Lanes:
    """Tasks shared between this process and a Dask cluster: this process takes tasks one at a time while the
    cluster starts (``run_here``); once it is up (``hand_over``, on the starting thread) every task not yet
    begun goes to the workers, and this process finishes the one it is running."""

    def __init__(self, fn: Callable, tasks: Sequence[tuple], shared: tuple, progress):
        self.fn, self.tasks, self.shared, self.progress = fn, tasks, shared, progress
        self.waiting = deque(range(len(tasks)))
        self.out: list = [None] * len(tasks)
        self.futures: dict = {}
        self.lock = threading.Lock()
        self.thread: threading.Thread | None = None
        self.client = self.cluster = self.error = None

    def start_local(self, workers: int | None) -> None:
        """Start the local cluster on a thread of its own (Dask imported here first, while the fork server
        imports its preload on the other core)."""
        self.t0 = time.perf_counter()
        method = _start_forkserver(self.fn)
        _import_dask()
        self.thread = threading.Thread(target=self._start, args=(workers, method), name="kincal-cluster-start",
                                       daemon=True)
        self.thread.start()

    def _start(self, workers, method) -> None:
        try:
            self.client, self.cluster = _local_cluster(workers, method)
            self.hand_over(self.client)
            log.info("local cluster ready after %.2f s; %d of %d tasks begun in this process meanwhile",
                     time.perf_counter() - self.t0, len(self.tasks) - len(self.futures), len(self.tasks))
        except BaseException as exc:  # re-raised on the calling thread by join()
            self.error = exc
            with self.lock:
                self.waiting.clear()
            self._close()

    def _close(self) -> None:
        for part in (self.client, self.cluster):
            if part is not None:
                part.close()

    def hand_over(self, client) -> None:
        """Every task not yet begun to ``client``'s workers (the shared arguments scattered once)."""
        shared = client.scatter(list(self.shared), broadcast=True, hash=False) if self.shared else []
        with self.lock:
            rest, self.waiting = list(self.waiting), deque()
        self.futures = {client.submit(single_threaded, self.fn, *shared, *self.tasks[i], pure=False): i for i in rest}

    def run_here(self) -> None:
        """Tasks in this process until none is left waiting (the cluster took them, or every one is done)."""
        while True:
            with self.lock:
                if not self.waiting:
                    return
                i = self.waiting.popleft()
            self.out[i] = single_threaded(self.fn, *self.shared, *self.tasks[i])
            if self.progress:
                self.progress(i)

    def join(self):
        """(client, cluster) once the cluster's start is over; its error raised here."""
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.client, self.cluster

    def abandon(self) -> None:
        """A task here raised: wait for the start and shut the cluster down."""
        self.thread.join()
        self._close()

    def gather(self) -> list:
        from dask.distributed import as_completed  # optional heavy dependency: only here

        for f in as_completed(list(self.futures)):
            i = self.futures[f]
            self.out[i] = f.result()
            if self.progress:
                self.progress(i)
        return self.out


def _import_dask():
    try:
        import dask  # optional heavy dependency: only here
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise KincalError(DASK_HINT) from None
    return dask, Client, LocalCluster


def _connect(workers: int | None, scheduler: str | None, fn: Callable | None = None):
    """(client, the local cluster it owns or None)."""
    if scheduler is None:
        return _local_cluster(workers, _start_forkserver(fn))
    _, Client, _ = _import_dask()
    try:
        return Client(scheduler, timeout="10s"), None
    except (OSError, TimeoutError) as exc:
        raise KincalError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({exc})") from None


# A local cluster's settings (read when it starts; the nannies pass them to their workers): Dask's statistical
# profiler samples a worker's running task every 10 ms, its monitors poll every 20-500 ms and the scheduler
# looks for work to steal every 100 ms, about a tenth of a core on two workers that a study's tasks have no use
# for. The scheduler's queue hands a worker its next task when it frees up (saturation 1: by default a worker
# holds a second one, which at the end can leave it a long task while the other worker has nothing left).
LOCAL_SETTINGS = {"distributed.worker.profile.enabled": False, "distributed.scheduler.work-stealing": False,
                  "distributed.scheduler.worker-saturation": 1.0,
                  "distributed.admin.tick.interval": "1s", "distributed.admin.system-monitor.interval": "5s",
                  "distributed.worker.memory.monitor-interval": "1s"}


def _local_cluster(workers: int | None, method: str):
    dask, Client, LocalCluster = _import_dask()
    n = default_workers() if workers is None else workers
    with dask.config.set({**LOCAL_SETTINGS, "distributed.worker.multiprocessing-method": method}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    try:
        return Client(cluster), cluster
    except BaseException:
        cluster.close()
        raise


def preload(fn: Callable | None) -> list[str]:
    """What the fork server imports once for every local worker it forks: Dask's worker and the task
    function's module (kincal's study or batch: with it NumPy, SciPy and the solver), nothing else."""
    module = getattr(fn, "__module__", None)
    return ["distributed"] + ([module] if module and module.startswith("kincal.") else [])


def _start_forkserver(fn: Callable | None = None) -> str:
    """The start method of local workers, with the forkserver started at once where there is one: it imports
    ``preload(fn)`` while this process imports Dask (on two cores, at the same time instead of one after the
    other).

    Workers forked from a clean server process start fast with kincal imported once, where forking this
    process itself (threads of its own, the caller's, BLAS pools) can deadlock a child on a held lock;
    spawned workers would import numpy, scipy and kincal again, seconds each."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    multiprocessing.set_forkserver_preload(preload(fn))
    forkserver.ensure_running()
    return "forkserver"
