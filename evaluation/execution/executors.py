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

import contextlib
import ctypes
import functools
import heapq
import itertools
import math
import multiprocessing
import os
import pickle
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, InvalidStateError, ProcessPoolExecutor, wait
from typing import Any

from snac_gym.evaluation.execution.memory import keep_freed_memory
from threadpoolctl import threadpool_limits

from snac_gym.common._signals import STOP_SIGNALS
from snac_gym.common.errors import ExecutorStopped
from snac_gym.kernels.compiled import EVALUATOR_KERNEL_MODULES, load_if_cached, warm_up_shared
from snac_gym.model.robots import ROBOTS
from snac_gym.policies import registry
from snac_gym.tasks import TASKS


class SerialExecutor:
    """Run jobs one after the other in this process."""

    description = "serial"
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


#: Signals that end a run: the parent handles them, a worker only dies of SIGTERM.
_STOP_SIGNALS = set(STOP_SIGNALS)
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
_PRELOAD = ["snac_gym.evaluation.execution.kernel_preload"]


def _registrations() -> bytes | None:
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
    """How workers are started: forked from this process only while it runs a single thread.

    A worker forked from a process with other threads copies every lock they hold at that instant
    (pytest-xdist's I/O thread, a progress bar's monitor, a thread pool), and one copied while held
    never opens in the worker: a test run hung that way. Forking a single-threaded process copies
    no held lock, and is the fastest start (nothing to import again). Otherwise the workers come
    from a fork server: a clean single-threaded process started once, with :data:`_PRELOAD`
    imported, to which the run's registrations are sent pickled (:func:`_registrations`); when
    those cannot be pickled (a lambda, a class defined in a function), forking stays the only way
    to give them to the workers.
    """
    if not sys.platform.startswith("linux"):
        return None  # the platform's default (spawn)
    if threading.active_count() == 1 or registrations is None:
        return "fork"
    return "forkserver"


def _init_worker(parent_pid: int, registrations: bytes | None = None, compile_locks: Sequence[Any] = ()) -> None:
    """Worker initialiser: die with the parent, leave Ctrl-C to it, one BLAS thread per process, the
    compiled kernels ready (compiled once among the workers, :func:`~snac_gym.kernels.compiled.warm_up_shared`).

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
    for signum in _STOP_SIGNALS - {signal.SIGTERM}:
        signal.signal(signum, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    threadpool_limits(1, user_api="blas")
    keep_freed_memory()
    if compile_locks:
        warm_up_shared(compile_locks)


def _noop(seconds: float) -> None:
    """Hold a worker briefly, so that the pool starts one process per start-up job."""
    time.sleep(seconds)


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
        registrations = _registrations()
        method = start_method(registrations)
        context = multiprocessing.get_context(method)
        if method == "forkserver":
            context.set_forkserver_preload(_PRELOAD)
        elif method == "fork":
            load_if_cached()  # once here, for every worker forked from here
        self.start_method = context.get_start_method()
        compile_locks = tuple(context.Lock() for _ in EVALUATOR_KERNEL_MODULES)
        self._pool = ProcessPoolExecutor(
            max_workers=workers,
            mp_context=context,
            initializer=_init_worker,
            initargs=(os.getpid(), registrations if method == "forkserver" else None, compile_locks),
        )
        # Start every worker now, from this thread (one job each, submitted together: the pool
        # starts a process per job while none is idle): the parent-death signal of a forked worker
        # follows the thread that forked it, and this one (the caller's) outlives the run.
        # The stop signals are blocked meanwhile: one arriving before a worker's initialiser
        # set its handlers would print that worker's traceback (the initialiser unblocks them).
        blocked = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
        if blocked:
            signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            try:
                started = [self._pool.submit(_noop, 0.05) for _ in range(workers)]
            finally:
                if blocked:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
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


#: Seconds ``--ray ADDRESS`` waits for a TCP connection to the cluster before giving up (Ray's
#: own client retries for minutes on an address that does not answer).
RAY_CONNECT_TIMEOUT_S = 10.0


def _ray_endpoint(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a cluster address, ``None`` for ``auto`` (found by Ray on this machine)."""
    if address == "auto":
        return None
    default_port = 10001 if address.startswith("ray://") else 6379
    rest = address.removeprefix("ray://")
    host, colon, port = rest.rpartition(":")
    if not colon:
        host, port = rest, str(default_port)
    host = host.strip("[]")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--ray {address!r}: use 'local', 'auto', HOST:PORT or ray://HOST:PORT")
    return host, int(port)


def check_ray_reachable(address: str, timeout: float | None = None) -> None:
    """Fail within ``timeout`` s (default :data:`RAY_CONNECT_TIMEOUT_S`) if the cluster at ``address`` does not answer.

    Raises:
        RuntimeError: If no TCP connection to it can be made in time.
        ValueError: If ``address`` is malformed.
    """
    endpoint = _ray_endpoint(address)
    if endpoint is None:
        return
    timeout = RAY_CONNECT_TIMEOUT_S if timeout is None else timeout
    try:
        with socket.create_connection(endpoint, timeout=timeout):
            pass
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise RuntimeError(
            f"--ray {address}: cannot reach the Ray cluster at {endpoint[0]}:{endpoint[1]} "
            f"within {timeout:g} s ({reason})"
        ) from None


@contextlib.contextmanager
def _handlers_kept() -> Iterator[None]:
    """Restore this process's stop-signal handlers after the block.

    ``ray.init`` installs a SIGTERM handler that ends the process at once (exit 15, no clean-up),
    which would bypass the run's interrupt path: the workers stopped, the one line, exit 143.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {signum: signal.getsignal(signum) for signum in _STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in saved.items():
            if handler is not None:
                signal.signal(signum, handler)


class RayExecutor:
    """Run jobs as Ray tasks on the cluster at ``address`` (``"local"``: a new local instance).

    Args:
        address: Ray address (``"auto"``, ``"ray://host:10001"``, ...) or ``"local"``.
        workers: CPUs of a ``"local"`` instance (ignored when joining a cluster).

    Raises:
        RuntimeError: If Ray is not installed, or the cluster does not answer within
            :data:`RAY_CONNECT_TIMEOUT_S`.
    """

    concurrent = True

    def __init__(self, address: str, workers: int | None = None) -> None:
        try:
            import ray  # the ray extra
        except ImportError as exc:
            raise RuntimeError("--ray needs Ray: pip install 'snac-gym[ray]'") from exc
        self._ray = ray
        self._started_here = not ray.is_initialized()
        with _handlers_kept():
            self._init_ray(ray, address, workers)
        self.description = f"Ray ({address})"
        self._remotes: dict[Callable[[Any], Any], Any] = {}
        self._lock = threading.Lock()
        self._stopped = threading.Event()

    def _init_ray(self, ray: Any, address: str, workers: int | None) -> None:
        if self._started_here:
            if address == "local":
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            else:
                check_ray_reachable(address)
                # Something answers (a proxy accepts any connection): bound Ray's own retries
                # (one per second) by the same timeout, unless the user set them.
                os.environ.setdefault("RAY_gcs_server_port_wait_time_s", str(math.ceil(RAY_CONNECT_TIMEOUT_S)))
                try:
                    ray.init(address=address, log_to_driver=False)
                except (ConnectionError, TimeoutError) as exc:
                    raise RuntimeError(
                        (
                            f"--ray {address}: no Ray cluster answered within {RAY_CONNECT_TIMEOUT_S:g} s ({exc})"
                        ).splitlines()[0]
                    ) from None

    def run(self, function: Callable[[Any], Any], items: Sequence[Any], priority: int = 0) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, result)`` as Ray tasks finish (``priority`` is left to Ray's scheduler)."""
        ray = self._ray
        with self._lock:  # several threads may call run at once
            if self._stopped.is_set():
                raise ExecutorStopped("the run was stopped")
            if function not in self._remotes:
                self._remotes[function] = ray.remote(function)
            remote = self._remotes[function]
        refs: dict[Any, int] = {remote.remote(item): index for index, item in enumerate(items)}
        try:
            while refs:
                # A bounded wait, so that terminate() (from another thread) ends this loop.
                done, _ = ray.wait(list(refs), num_returns=1, timeout=self.POLL_S)
                if self._stopped.is_set():
                    raise ExecutorStopped("the run was stopped")
                for ref in done:
                    yield refs.pop(ref), ray.get(ref)
        finally:
            for ref in refs:
                ray.cancel(ref, force=True)

    #: Seconds between checks for :meth:`terminate` while waiting on Ray tasks.
    POLL_S = 0.2

    def terminate(self) -> None:
        """Stop now: every :meth:`run` ends within :attr:`POLL_S` and cancels its tasks; :meth:`close` stops a local
        instance."""
        self._stopped.set()

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


@contextlib.contextmanager
def open_executor(
    workers: int = 1, ray_address: str | None = None
) -> Iterator[SerialExecutor | ProcessExecutor | RayExecutor]:
    """:func:`make_executor` for the length of a block: closed after it, and terminated first if the block
    raises or is interrupted (a failed or interrupted run does not wait for the jobs still running)."""
    executor = make_executor(workers, ray_address)
    try:
        yield executor
    except BaseException:
        executor.terminate()
        raise
    finally:
        executor.close()
