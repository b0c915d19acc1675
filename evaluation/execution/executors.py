"""Where jobs run: in this process, in local worker processes, or on a Ray cluster.

Every executor maps a module-level function over a list of picklable items (rollout jobs,
sample-generation chunks) and yields ``(index, result)`` pairs as items complete, in
completion order; the caller stores each result as it arrives. The functions are pure, so
where they run does not change what they return.

* :class:`SerialExecutor`: one job after the other, here (``--workers 1``).
* :class:`ProcessExecutor`: a pool of local processes (``--workers N``). It forks where the
  platform allows, so policies registered at run time with :func:`snac_gym.register_policy`
  are known to the workers.
* :class:`RayExecutor`: Ray tasks (``--ray ADDRESS``; ``local`` starts a Ray instance on this
  machine, ``auto`` joins the cluster this machine belongs to). Ray is the optional extra
  ``ray``. Workers resolve controllers by name, so only built-in and entry-point policies
  (not ones registered at run time) can be used.

The workers' start is in :mod:`~snac_gym.evaluation.execution.worker_setup`, the Ray executor in
:mod:`~snac_gym.evaluation.execution.ray_executor`; their public names are importable from here.
"""

from __future__ import annotations

import contextlib
import functools
import heapq
import itertools
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, InvalidStateError, ProcessPoolExecutor, wait
from typing import Any

from snac_gym.evaluation.execution.ray_executor import (
    RAY_CONNECT_TIMEOUT_S,
    RayExecutor,
    check_ray_reachable,
    ray_endpoint,
)
from snac_gym.evaluation.execution.worker_setup import (
    PRELOAD,
    RUN_STOP_SIGNALS,
    init_worker,
    noop,
    run_registrations,
    start_method,
)

from snac_gym.common.errors import ExecutorStopped
from snac_gym.kernels.compiled import EVALUATOR_KERNEL_MODULES, load_if_cached

__all__ = [
    "MAX_WORKERS_PER_CPU",
    "RAY_CONNECT_TIMEOUT_S",
    "ExecutorStopped",
    "ProcessExecutor",
    "RayExecutor",
    "SerialExecutor",
    "available_cpus",
    "check_ray_reachable",
    "make_executor",
    "max_workers",
    "open_executor",
    "ray_endpoint",
    "start_method",
]


class SerialExecutor:
    """Run jobs one after the other in this process."""

    description = "serial"
    #: Jobs that run at once.
    workers = 1
    #: Whether several threads may feed it jobs at once (and gain from it).
    concurrent = False

    def run(self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, function(item))`` in order (``priority`` is ignored: one job at a time)."""
        for index, item in enumerate(items):
            yield index, function(item)

    def terminate(self) -> None:
        """Nothing runs outside the caller's thread."""

    def close(self) -> None:
        """Nothing to release."""


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: ``--workers`` is at most this many per available CPU: beyond the cores, more processes only
#: add memory and start-up time (each holds a Pinocchio model and the policies).
MAX_WORKERS_PER_CPU = 2


def max_workers() -> int:
    """The largest ``--workers`` accepted on this machine."""
    return MAX_WORKERS_PER_CPU * available_cpus()


class ProcessExecutor:
    """Run jobs on ``workers`` local processes (kept for the whole evaluation), one BLAS thread each.

    Several threads may call :meth:`run` at once (the concurrent effort matches); their jobs
    share the pool through one queue ordered by ``priority`` (lower first), then by arrival.
    Only ``workers`` jobs are handed to the pool at a time, so a job of higher priority
    submitted later (a knob search's next evaluation, on which a whole chain of work waits)
    starts as soon as a worker is free instead of behind every queued full pass; with
    :meth:`reserve`, some workers are also kept free of jobs of priority above 0, so that such a
    job does not even wait for a running full pass to end.
    """

    concurrent = True

    def __init__(self, workers: int, kernel_modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers
        self.description = f"{workers} local processes"
        self._lock = threading.Lock()
        self._queue: list[tuple[int, int, Callable[[Any], Any], Any, Future]] = []
        self._arrivals = itertools.count()
        self._running = 0
        self._running_low = 0  # running jobs of priority above 0
        self._reserved = 0
        # Jobs handed to the pool and not yet finished: terminate() fails them itself, since a
        # pool whose workers were killed does not always complete their futures (an interrupted
        # run hung in effort matching, its threads waiting on futures of a dead pool).
        self._dispatched: set[Future] = set()
        self._stopped = False
        registrations = run_registrations()
        method = start_method(registrations)
        context = multiprocessing.get_context(method)
        if method == "forkserver":
            context.set_forkserver_preload(PRELOAD)
        elif method == "fork":
            load_if_cached(kernel_modules)  # once here, for every worker forked from here
        self.start_method = context.get_start_method()
        compile_locks = tuple(context.Lock() for _ in kernel_modules)
        self._pool = ProcessPoolExecutor(
            max_workers=workers,
            mp_context=context,
            initializer=init_worker,
            initargs=(os.getpid(), registrations if method == "forkserver" else None, compile_locks, kernel_modules),
        )
        # Start every worker now, from this thread (one job each, submitted together: the pool
        # starts a process per job while none is idle): the parent-death signal of a forked worker
        # follows the thread that forked it, and this one (the caller's) outlives the run.
        # The stop signals are blocked meanwhile: one arriving before a worker's initialiser
        # set its handlers would print that worker's traceback (the initialiser unblocks them).
        blocked = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
        if blocked:
            signal.pthread_sigmask(signal.SIG_BLOCK, RUN_STOP_SIGNALS)
        try:
            try:
                started = [self._pool.submit(noop, 0.05) for _ in range(workers)]
            finally:
                if blocked:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, RUN_STOP_SIGNALS)
            for future in started:
                future.result()
        except BaseException:  # interrupted while starting: no caller holds this executor to close it
            self.terminate()
            self._pool.shutdown(wait=True, cancel_futures=True)
            raise

    def reserve(self, slots: int) -> None:
        """Keep ``slots`` workers (at most ``workers − 1``) free of jobs of priority above 0 until changed."""
        with self._lock:
            self._reserved = max(0, min(int(slots), self.workers - 1))
            handed = self._dispatch()
        self._watch(handed)

    def _dispatch(self) -> list[tuple[Future, Callable[[Future], None]]]:
        """Hand queued jobs to the pool while workers are free (call with the lock held).

        Returns each job's pool future with the callback that ends it, for :meth:`_watch` to
        attach once the lock is released: a job that is already done when its callback is attached
        runs the callback at once, in the attaching thread, and the callback takes the lock (attached
        here, with the lock held, that deadlocked a run whose jobs were quick).
        """
        handed: list[tuple[Future, Callable[[Future], None]]] = []
        while not self._stopped and self._running < self.workers and self._queue:
            priority = self._queue[0][0]
            low = priority > 0
            if low and self._running_low >= self.workers - self._reserved:
                break  # the queue head is the most urgent job: the rest is low priority too
            _, _, function, item, outer = heapq.heappop(self._queue)
            if not outer.set_running_or_notify_cancel():
                continue
            try:
                inner = self._pool.submit(function, item)
            except BaseException as exc:  # noqa: BLE001 - the pool is shut down or broken: the caller's future gets it
                outer.set_exception(exc)
                continue
            self._running += 1
            self._running_low += low
            self._dispatched.add(outer)
            handed.append((inner, functools.partial(self._finished, outer, low)))
        return handed

    @staticmethod
    def _watch(handed: list[tuple[Future, Callable[[Future], None]]]) -> None:
        """Attach the callbacks :meth:`_dispatch` returned (call without the lock)."""
        for inner, finished in handed:
            inner.add_done_callback(finished)

    def _finished(self, outer: Future, low: bool, inner: Future) -> None:
        with self._lock:
            self._running -= 1
            self._running_low -= low
            self._dispatched.discard(outer)
            handed = self._dispatch()
        self._watch(handed)
        if outer.done():  # already failed by terminate()
            return
        if inner.cancelled():
            outer.set_exception(ExecutorStopped("the job was cancelled"))  # pragma: no cover - only at shutdown
        elif inner.exception() is not None:
            outer.set_exception(inner.exception())
        else:
            outer.set_result(inner.result())

    def run(self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0) -> Iterator[tuple[int, Any]]:
        futures: dict[Future, int] = {}
        with self._lock:
            if self._stopped:
                raise ExecutorStopped("the run was stopped")
            for index, item in enumerate(items):
                outer: Future = Future()
                heapq.heappush(self._queue, (priority, next(self._arrivals), function, item, outer))
                futures[outer] = index
            handed = self._dispatch()
        self._watch(handed)
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()  # the ones still queued; running jobs finish in their worker

    def terminate(self) -> None:
        """Stop now (an interrupted run): drop the queue, fail every job still waited on and end the
        workers without waiting for their jobs. Every thread blocked in :meth:`run` returns at once
        (with :class:`ExecutorStopped`), and later calls of :meth:`run` raise it."""
        with self._lock:
            self._stopped = True
            self._drop_queue()
            dispatched, self._dispatched = list(self._dispatched), set()
        for outer in dispatched:
            with contextlib.suppress(InvalidStateError):  # it finished meanwhile
                outer.set_exception(ExecutorStopped("the run was stopped while this job ran"))
        # The pool has no public way to stop running jobs; its worker table is stable across
        # CPython 3.8-3.13, and without it close() still ends the workers after their jobs.
        for process in list((getattr(self._pool, "_processes", None) or {}).values()):
            if process.is_alive():
                process.terminate()

    def _drop_queue(self) -> None:
        """Cancel the queued jobs (call with the lock held)."""
        for *_, outer in self._queue:
            # cancel() alone does not wake a thread blocked in wait() on the future (only
            # set_running_or_notify_cancel notifies waiters of a cancellation): that was the hang
            # of an interrupted effort match.
            outer.cancel()
            outer.set_running_or_notify_cancel()
        self._queue.clear()

    def close(self) -> None:
        with self._lock:
            self._drop_queue()
        self._pool.shutdown(wait=True, cancel_futures=True)


def make_executor(
    workers: int = 1, ray_address: str | None = None, kernel_modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES
) -> SerialExecutor | ProcessExecutor | RayExecutor:
    """The executor for ``--workers`` and ``--ray``; local worker processes compile or load ``kernel_modules``'
    kernels when they start (:func:`~snac_gym.kernels.compiled.evaluator_kernel_modules`)."""
    if ray_address:
        return RayExecutor(ray_address, workers)
    if workers > 1:
        return ProcessExecutor(workers, kernel_modules)
    return SerialExecutor()


@contextlib.contextmanager
def open_executor(
    workers: int = 1, ray_address: str | None = None, kernel_modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES
) -> Iterator[SerialExecutor | ProcessExecutor | RayExecutor]:
    """:func:`make_executor` for the length of a block: closed after it, and terminated first if the block
    raises or is interrupted (a failed or interrupted run does not wait for the jobs still running)."""
    executor = make_executor(workers, ray_address, kernel_modules)
    try:
        yield executor
    except BaseException:
        executor.terminate()
        raise
    finally:
        executor.close()
