"""The Dask back end of kincal study and batch (``kincal.workflow.parallel``): this process runs tasks while its
local cluster starts and hands the rest over once the workers are up; shared arguments travel once; the
study's table is the same whoever ran which repeat."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from dataclasses import replace

import cloudpickle
import numpy as np
import pytest

from kincal.workflow import parallel
from kincal.workflow import study as S

distributed = pytest.importorskip("distributed")


def _table1(repeats: int) -> S.Study:
    s = S.load("table1")
    return replace(s, repeats=repeats, variants=tuple(v for v in s.variants if v.name in ("approach2", "approach1")))


def _where(i, shared):
    """Task ``i``: its index, the shared object's id in the process that ran it, and whether this process's main
    thread ran it (the thread-based cluster below runs tasks on threads of its own)."""
    return i, id(shared), os.getpid(), threading.current_thread() is threading.main_thread()


RAN_THREE, HANDED = threading.Event(), threading.Event()  # module level: tasks are pickled by reference


def _held_task(shared, i):
    if threading.current_thread() is threading.main_thread():
        if i == 2:
            RAN_THREE.set()
        if i == 3:
            assert HANDED.wait(60)
    return _where(i, shared)


def test_this_process_runs_tasks_until_the_cluster_takes_the_rest(monkeypatch):
    """The cluster's start is held until this process has run three tasks; the fourth blocks until the hand-over
    is done, so this process ran exactly tasks 0-3 and the cluster the others, all results in task order."""
    RAN_THREE.clear(), HANDED.clear()
    real_hand_over = parallel._Lanes.hand_over

    def held_start(workers, method):
        assert RAN_THREE.wait(60)
        cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                           dashboard_address=None)
        return distributed.Client(cluster), cluster

    def hand_over(self, client):
        real_hand_over(self, client)
        HANDED.set()

    monkeypatch.setattr(parallel, "_local_cluster", held_start)
    monkeypatch.setattr(parallel._Lanes, "hand_over", hand_over)
    shared = {"the": "study"}
    done = []
    out = parallel.run_tasks(_held_task, [(i,) for i in range(12)], workers=1, progress=done.append,
                             shared=(shared,))
    assert [o[0] for o in out] == list(range(12)) and sorted(done) == list(range(12))
    assert [o[3] for o in out] == [True] * 4 + [False] * 8
    assert {o[1] for o in out[:4]} == {id(shared)}  # this process: the object itself
    assert len({o[1] for o in out[4:]}) == 1  # the worker: one object for all its tasks


def test_a_task_failing_here_shuts_the_starting_cluster_down(monkeypatch):
    closed = []

    class Part:
        def close(self):
            closed.append(self)

    started = threading.Event()

    def held_start(workers, method):
        started.wait(60)
        return Part(), Part()

    def task(i):
        started.set()
        raise ValueError(f"task {i} failed")

    monkeypatch.setattr(parallel, "_local_cluster", held_start)
    monkeypatch.setattr(parallel._Lanes, "hand_over", lambda self, client: None)
    with pytest.raises(ValueError, match="task 0 failed"):
        parallel.run_tasks(task, [(i,) for i in range(3)], workers=1)
    assert len(closed) == 2


def test_workers_alone_give_the_same_table_as_this_process(monkeypatch):
    """With this process kept out (every task on the two worker processes) the table is the one of the inline
    run: the repeats' seeds, the fixed parts sent once, the workers' own memo."""
    s = _table1(12)
    inline = S.table(S.run_study(s, workers=0))
    monkeypatch.setattr(parallel, "HERE_WHILE_STARTING", False)
    assert S.table(S.run_study(s, workers=2, chunks=4)) == inline


def _pid_and_shared(shared, i):
    return i, os.getpid(), id(shared)


def test_shared_arguments_reach_each_worker_process_once(monkeypatch):
    monkeypatch.setattr(parallel, "HERE_WHILE_STARTING", False)
    out = parallel.run_tasks(_pid_and_shared, [(i,) for i in range(8)], workers=2, shared=({"the": "study"},))
    assert [o[0] for o in out] == list(range(8)) and os.getpid() not in {o[1] for o in out}
    per_process = {}
    for _, pid, ident in out:
        per_process.setdefault(pid, set()).add(ident)
    assert all(len(ids) == 1 for ids in per_process.values())


def test_fixed_parts_travel_without_their_memo():
    s = _table1(3)
    fixed = S.fixed_parts(s)
    S.run_chunk(s, fixed, range(2))
    assert fixed.memo
    copy = pickle.loads(cloudpickle.dumps(fixed))  # as Dask sends it
    assert copy.memo == {} and copy.true is not None
    assert np.array_equal(copy.q_validation["arm"], fixed.q_validation["arm"])
    assert S.table(S.summarize(s, S.run_chunk(s, copy, range(3)))) == S.table(S.summarize(s, S.run_chunk(s, fixed,
                                                                                                      range(3))))


def test_task_bounds_end_with_short_tasks():
    b = S.task_bounds(1000, 3)
    sizes = np.diff(b)
    assert b[0] == 0 and b[-1] == 1000 and sizes.min() > 0
    assert list(sizes[-6:]) == [S.TAIL_REPEATS] * 6 and sizes.max() <= S.REPEATS_PER_TASK
    assert list(S.task_bounds(7, 3)) == [0, 3, 7] and list(S.task_bounds(0, 3)) == [0]


def test_preload_is_the_task_module_and_dask():
    assert parallel.preload(S.run_chunk) == ["distributed", "kincal.workflow.study"]
    assert parallel.preload(lambda: None) == ["distributed"]


def test_a_study_worker_does_not_import_the_job_machinery():
    """The fork server imports the study's module: not the job runner with the thesis baseline and its
    scipy.optimize (``kincal.workflow`` imports ``run_job`` on first use, and ``run_job`` still reaches it)."""
    code = ("import sys, kincal.workflow.study; print(sorted(m for m in ('scipy.optimize', 'kincal.baselines', "
            "'kincal.workflow.jobs') if m in sys.modules)); from kincal.workflow import run_job; "
            "print(run_job.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["[]", "kincal.workflow.jobs"]
