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
"""

from __future__ import annotations

import functools
import heapq
import itertools
import multiprocessing
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any


class SerialExecutor:
    """Run jobs one after the other in this process."""

    description = "serial"
    #: Whether several threads may feed it jobs at once (and gain from it).
    concurrent = False

    def run(
        self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, function(item))`` in order (``priority`` is ignored: one job at a time)."""
        for index, item in enumerate(items):
            yield index, function(item)

    def close(self) -> None:
        """Nothing to release."""


def _single_threaded_blas() -> None:
    """Worker initialiser: one BLAS thread per process.

    The workers already use every core; BLAS threads on top of them (OpenBLAS starts one per
    core in each process) contend for the cores and made the full passes of Table I 1.5x
    slower (42.7 s against 28.4 s, docs/evaluation.md).
    """
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


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

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers
        self.description = f"{workers} local processes"
        method = "fork" if sys.platform.startswith("linux") else None
        self._pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=multiprocessing.get_context(method), initializer=_single_threaded_blas
        )
        self._lock = threading.Lock()
        self._queue: list[tuple[int, int, Callable[[Any], Any], Any, Future]] = []
        self._arrivals = itertools.count()
        self._running = 0
        self._running_low = 0  # running jobs of priority above 0
        self._reserved = 0

    def reserve(self, slots: int) -> None:
        """Keep ``slots`` workers (at most ``workers − 1``) free of jobs of priority above 0 until changed."""
        with self._lock:
            self._reserved = max(0, min(int(slots), self.workers - 1))
            self._dispatch()

    def _dispatch(self) -> None:
        """Hand queued jobs to the pool while workers are free (call with the lock held)."""
        while self._running < self.workers and self._queue:
            priority = self._queue[0][0]
            low = priority > 0
            if low and self._running_low >= self.workers - self._reserved:
                return  # the queue head is the most urgent job: the rest is low priority too
            _, _, function, item, outer = heapq.heappop(self._queue)
            if not outer.set_running_or_notify_cancel():
                continue
            try:
                inner = self._pool.submit(function, item)
            except BaseException as exc:  # the pool is shut down or broken
                outer.set_exception(exc)
                continue
            self._running += 1
            self._running_low += low
            inner.add_done_callback(functools.partial(self._finished, outer, low))

    def _finished(self, outer: Future, low: bool, inner: Future) -> None:
        with self._lock:
            self._running -= 1
            self._running_low -= low
            self._dispatch()
        if inner.cancelled():
            outer.cancel()  # pragma: no cover - inner futures are only cancelled at shutdown
        elif inner.exception() is not None:
            outer.set_exception(inner.exception())
        else:
            outer.set_result(inner.result())

    def run(
        self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0
    ) -> Iterator[tuple[int, Any]]:
        futures: dict[Future, int] = {}
        with self._lock:
            for index, item in enumerate(items):
                outer: Future = Future()
                heapq.heappush(self._queue, (priority, next(self._arrivals), function, item, outer))
                futures[outer] = index
            self._dispatch()
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()  # the ones still queued; running jobs finish in their worker

    def close(self) -> None:
        with self._lock:
            for *_, outer in self._queue:
                outer.cancel()
            self._queue.clear()
        self._pool.shutdown(wait=True, cancel_futures=True)


class RayExecutor:
    """Run jobs as Ray tasks on the cluster at ``address`` (``"local"``: a new local instance).

    Args:
        address: Ray address (``"auto"``, ``"ray://host:10001"``, ...) or ``"local"``.
        workers: CPUs of a ``"local"`` instance (ignored when joining a cluster).

    Raises:
        RuntimeError: If Ray is not installed.
    """

    concurrent = True

    def __init__(self, address: str, workers: int | None = None) -> None:
        try:
            import ray
        except ImportError as exc:
            raise RuntimeError("--ray needs Ray: pip install 'snac-gym[ray]'") from exc
        self._ray = ray
        self._started_here = not ray.is_initialized()
        if self._started_here:
            if address == "local":
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=address, log_to_driver=False)
        self.description = f"Ray ({address})"
        self._remotes: dict[Callable[[Any], Any], Any] = {}
        self._lock = threading.Lock()

    def run(
        self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, result)`` as Ray tasks finish (``priority`` is left to Ray's scheduler)."""
        ray = self._ray
        with self._lock:  # several threads may call run at once
            if function not in self._remotes:
                self._remotes[function] = ray.remote(function)
            remote = self._remotes[function]
        refs: dict[Any, int] = {remote.remote(item): index for index, item in enumerate(items)}
        try:
            while refs:
                done, _ = ray.wait(list(refs), num_returns=1)
                for ref in done:
                    yield refs.pop(ref), ray.get(ref)
        finally:
            for ref in refs:
                ray.cancel(ref)

    def close(self) -> None:
        if self._started_here:
            self._ray.shutdown()


def make_executor(workers: int = 1, ray_address: str | None = None) -> SerialExecutor | ProcessExecutor | RayExecutor:
    """The executor for ``--workers`` and ``--ray``."""
    if ray_address:
        return RayExecutor(ray_address, workers)
    if workers > 1:
        return ProcessExecutor(workers)
    return SerialExecutor()
