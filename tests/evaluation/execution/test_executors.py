"""Worker processes are started safely: forked only from a single-threaded process, otherwise from a
fork server that receives the run's registrations."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
from snac_gym.evaluation.execution.executors import ProcessExecutor, start_method

from snac_gym.policies import registry


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="fork and forkserver are Linux's")
def test_workers_come_from_a_fork_server_while_other_threads_run_and_know_the_registrations():
    registry.register_policy("forkserver-test-dls", "snac_gym.baselines.dls:DLSPolicy", overwrite=True)
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)  # as pytest-xdist's I/O thread would be
    other.start()
    try:
        executor = ProcessExecutor(2)
        try:
            assert executor.start_method == "forkserver"
            found = dict(executor.run(registry.policy_factory, ["forkserver-test-dls"]))
            assert found[0].__name__ == "DLSPolicy"  # registered here at run time, resolved in a worker
        finally:
            executor.close()
    finally:
        stop.set()
        other.join()
        registry._BUILTIN.pop("forkserver-test-dls", None)


def test_a_single_threaded_process_forks_and_unpicklable_registrations_force_fork():
    assert start_method(b"registrations") == ("fork" if threading.active_count() == 1 else "forkserver")
    assert start_method(None) == "fork"  # a lambda registered as a policy reaches workers only by fork


class _DonePool:
    """A pool whose jobs are done before ``submit`` returns: the race a quick job wins against the
    attaching of its callback."""

    def __init__(self) -> None:
        self.submitted = 0

    def submit(self, function, item):
        from concurrent.futures import Future

        self.submitted += 1
        future: Future = Future()
        future.set_result(function(item))
        return future


@pytest.mark.parametrize("priority", [0, 1], ids=["urgent", "low-priority-with-a-reserved-worker"])
def test_a_job_done_before_its_callback_is_attached_does_not_deadlock_the_executor(priority):
    executor = ProcessExecutor(2)
    real_pool = executor._pool
    try:
        executor._pool = _DonePool()
        executor.reserve(1)  # low-priority jobs then run one at a time: the dispatch stops at the queue head
        results: dict[int, int] = {}
        jobs = [-3, -1, -2, 4]
        worker = threading.Thread(target=lambda: results.update(executor.run(abs, jobs, priority)), daemon=True)
        worker.start()
        worker.join(timeout=30)
        assert not worker.is_alive(), "the executor deadlocked on a job that finished before its callback"
        assert results == {0: 3, 1: 1, 2: 2, 3: 4} and executor._pool.submitted == 4
        assert executor._running == 0
    finally:
        executor._pool = real_pool
        executor.close()


#: memory.py loaded from its file: the function the workers call, without the evaluator's imports (half a
#: second per process; the module needs only ctypes).
_FAULTS = """
import importlib.util, resource, sys
import numpy as np
spec = importlib.util.spec_from_file_location("memory", sys.argv[2])
memory = importlib.util.module_from_spec(spec)
spec.loader.exec_module(memory)
kept = memory.keep_freed_memory() if sys.argv[1] == "kept" else False
np.ones((1000, 2500, 6))  # 120 MB, freed at once
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
np.ones((1000, 2500, 6))
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_worker_reuses_a_freed_rollout_log_instead_of_faulting_in_new_pages():
    """By default the second 120 MB array is faulted in afresh (at least one fault per 2 MB huge page, 30 000
    without huge pages); in a process set up as the workers are (evaluation/execution/memory.py) it reuses the
    first's."""
    from snac_gym.evaluation.execution import memory

    faults = {}
    for mode in ("default", "kept"):
        command = [sys.executable, "-c", _FAULTS, mode, memory.__file__]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        kept, faults[mode] = done.stdout.split()
        assert kept == ("True" if mode == "kept" else "False")
    assert int(faults["default"]) >= 60 and int(faults["kept"]) < 10, faults
