"""Worker processes are started safely: forked only from a single-threaded process, otherwise from a
fork server that receives the run's registrations."""

from __future__ import annotations

import threading

import pytest

from evaluation.executors import ProcessExecutor, start_method
from snac_gym.policies import registry


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="fork and forkserver are Linux's")
def test_workers_come_from_a_fork_server_while_other_threads_run_and_know_the_registrations():
    registry.register_policy("forkserver-test-dls", "baselines.dls:DLSPolicy", overwrite=True)
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
