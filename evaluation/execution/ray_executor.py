"""Jobs on a Ray cluster (``--ray ADDRESS``): :class:`RayExecutor`, and the reachability check that fails fast on an
address that does not answer.

Part of :mod:`snac_gym.evaluation.execution.executors`; Ray itself is the optional extra ``ray``, imported only when
a :class:`RayExecutor` is made.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from snac_gym.evaluation.execution.worker_setup import RUN_STOP_SIGNALS

from snac_gym.common.errors import ExecutorStopped
from snac_gym.common.extras import require

__all__ = ["RAY_CONNECT_TIMEOUT_S", "RayExecutor", "check_ray_reachable", "ray_endpoint"]

#: Seconds ``--ray ADDRESS`` waits for a TCP connection to the cluster before giving up (Ray's
#: own client retries for minutes on an address that does not answer).
RAY_CONNECT_TIMEOUT_S = 10.0
#: Ray's notice, as it starts a local instance, that the instance uses token authentication (its default): nothing for
#: the user to do, and two lines of log before the run's own. Its warning that authentication is *off* still shows.
RAY_TOKEN_NOTICE = "Token authentication is enabled for this Ray cluster"
_RAY_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"


def ray_endpoint(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a cluster address, ``None`` for ``auto`` (found by Ray on this machine).

    Raises:
        ValueError: If ``address`` is malformed (read without Ray: a wrong address is named before a missing extra).
    """
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
    endpoint = ray_endpoint(address)
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
    saved = {signum: signal.getsignal(signum) for signum in RUN_STOP_SIGNALS}
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
        MissingExtraError: If Ray (the ``ray`` extra) is not installed.
        RuntimeError: If the cluster does not answer within :data:`RAY_CONNECT_TIMEOUT_S`.
    """

    concurrent = True

    def __init__(self, address: str, workers: int | None = None) -> None:
        ray = require("ray", "ray", "--ray")
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
                # Ray's INFO lines ("Started a local Ray instance.") off too: the run's progress says what runs.
                with _without_token_notice():
                    ray.init(
                        num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING
                    )
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


class _TokenNoticeFilter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return RAY_TOKEN_NOTICE not in record.getMessage()


@contextlib.contextmanager
def _without_token_notice() -> Iterator[None]:
    """:data:`RAY_TOKEN_NOTICE` left out of Ray's log while a local instance starts."""
    logger, notice = logging.getLogger(_RAY_TOKEN_LOGGER), _TokenNoticeFilter()
    logger.addFilter(notice)
    try:
        yield
    finally:
        logger.removeFilter(notice)
