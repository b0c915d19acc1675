"""How the evaluator's local worker processes start and live: forked or from a fork server, with the run's
registrations, one BLAS thread each, Ctrl-C left to the parent, and gone when the parent dies.

Part of :mod:`snac_gym.evaluation.execution.executors`, whose
:class:`~snac_gym.evaluation.execution.executors.ProcessExecutor` starts its pool with :func:`init_worker`: the
workers' start is a matter of processes and signals, the pool's scheduling another.
"""

from __future__ import annotations

import ctypes
import os
import pickle
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from snac_gym.evaluation.execution.memory import keep_freed_memory
from threadpoolctl import threadpool_limits

from snac_gym.common._signals import STOP_SIGNALS
from snac_gym.kernels.compiled import EVALUATOR_KERNEL_MODULES, warm_up_shared
from snac_gym.model.robots import ROBOTS
from snac_gym.policies import registry
from snac_gym.tasks import TASKS

__all__ = ["PRELOAD", "RUN_STOP_SIGNALS", "init_worker", "noop", "run_registrations", "start_method"]

#: Signals that end a run: the parent handles them, a worker only dies of SIGTERM.
RUN_STOP_SIGNALS = set(STOP_SIGNALS)
#: Linux ``prctl`` option that sends a signal to a process when its parent dies.
_PR_SET_PDEATHSIG = 1


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs: a zombie (dead, not yet reaped by its own parent) counts as dead."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - another user's process has that pid now
        return True
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:  # pragma: no cover - no /proc: trust kill()
        return True


def _die_with_parent(parent_pid: int) -> None:
    """Make this worker exit when the process that started the run dies, however it dies (even SIGKILL).

    Orphaned workers would otherwise run on, holding the parent's stdout open, so that a reader
    of its pipe waits for ever. A worker's parent is the fork server, and the fork server lives
    as long as any worker holds its "alive" pipe (multiprocessing passes it to every worker), so
    the kernel's parent-death signal alone would wait on itself: a thread watching the run's pid
    (a zombie counts as dead: the run's own parent may not have reaped it yet) ends the worker,
    then the fork server exits, and the signal ends any worker still forked from it.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass

    def watch() -> None:
        while _alive(parent_pid):
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    if not _alive(parent_pid):  # the run ended before the signal was armed
        os._exit(1)


#: Modules the fork server imports once, so that each worker it forks starts with them, and the
#: kernels from numba's cache, loaded.
PRELOAD = ["snac_gym.evaluation.execution.kernel_preload"]


def run_registrations() -> bytes | None:
    """What was registered at run time (policies, tasks, robots), pickled for the workers; ``None``
    if some entry cannot be pickled (a lambda, a class defined in a function)."""
    try:
        return pickle.dumps((dict(registry._BUILTIN), dict(registry._FACTORIES), dict(TASKS), dict(ROBOTS)))
    except (pickle.PicklingError, AttributeError, TypeError):
        return None


def _install_registrations(data: bytes) -> None:
    builtin, factories, tasks, robots = pickle.loads(data)
    registry._BUILTIN.update(builtin)
    registry._FACTORIES.update(factories)
    TASKS.update(tasks)
    ROBOTS.update(robots)


def start_method(registrations: bytes | None) -> str | None:
    """How workers are started: forked from this process only while it runs a single Python thread.

    A worker forked from a process with other Python threads copies every lock they hold at that
    instant (pytest-xdist's I/O thread, a progress bar's monitor, a thread pool), and one copied
    while held never opens in the worker: a test run hung that way. The native threads always there
    (OpenBLAS's pools, pyarrow's jemalloc) register fork handlers that settle their locks, so Python
    3.12's warning about them is no hazard here. Forking then copies no held lock, and is the
    fastest start (nothing to import again). Otherwise the workers come from a fork server: a clean
    single-threaded process started once, with :data:`PRELOAD` imported, to which the run's
    registrations are sent pickled (:func:`run_registrations`); when those cannot be pickled (a
    lambda, a class defined in a function), forking stays the only way to give them to the workers.
    """
    if not sys.platform.startswith("linux"):
        return None  # the platform's default (spawn)
    if threading.active_count() == 1 or registrations is None:
        return "fork"
    return "forkserver"


def init_worker(
    parent_pid: int,
    registrations: bytes | None = None,
    compile_locks: Sequence[Any] = (),
    kernel_modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES,
) -> None:
    """Worker initialiser: die with the parent, leave Ctrl-C to it, one BLAS thread per process, the
    compiled kernels of ``kernel_modules`` ready (compiled once among the workers, one lock each of ``compile_locks``:
    :func:`~snac_gym.kernels.compiled.warm_up_shared`).

    SIGINT reaches every process of the terminal's foreground group; the parent stops the run
    and ends the workers, so a worker ignores it rather than printing its own traceback.

    The workers already use every core; BLAS threads on top of them (OpenBLAS starts one per
    core in each process) contend for the cores and made the full passes of Table I 1.5x
    slower (42.7 s against 28.4 s, docs/evaluation.md).
    """
    _die_with_parent(parent_pid)
    if registrations is not None:
        _install_registrations(registrations)
    # SIGINT (Ctrl-C), SIGHUP (a closed terminal) and SIGQUIT (Ctrl-\\) reach the whole foreground group:
    # the parent ends the run and its workers. A forked worker inherits the parent's handlers; the
    # CLI's turns SIGTERM into KeyboardInterrupt, which in a worker would print a traceback when the
    # parent ends it.
    for signum in RUN_STOP_SIGNALS - {signal.SIGTERM}:
        signal.signal(signum, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, RUN_STOP_SIGNALS)
    threadpool_limits(1, user_api="blas")
    keep_freed_memory()
    if compile_locks:
        warm_up_shared(compile_locks, kernel_modules)


def noop(seconds: float) -> None:
    """Hold a worker briefly, so that the pool starts one process per start-up job."""
    time.sleep(seconds)
