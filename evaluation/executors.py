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

import multiprocessing
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any


class SerialExecutor:
    """Run jobs one after the other in this process."""

    description = "serial"

    def run(self, function: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        for index, item in enumerate(items):
            yield index, function(item)

    def close(self) -> None:
        """Nothing to release."""


class ProcessExecutor:
    """Run jobs on ``workers`` local processes (kept for the whole evaluation).

    At most ``2 × workers`` jobs are in flight, so results stream back while the rest wait.
    """

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers
        self.description = f"{workers} local processes"
        method = "fork" if sys.platform.startswith("linux") else None
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method))

    def run(self, function: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        pending: dict[Future, int] = {}
        queue = iter(enumerate(items))
        try:
            while True:
                while len(pending) < 2 * self.workers:
                    item = next(queue, None)
                    if item is None:
                        break
                    pending[self._pool.submit(function, item[1])] = item[0]
                if not pending:
                    return
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    index = pending.pop(future)
                    yield index, future.result()
        finally:
            for future in pending:
                future.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class RayExecutor:
    """Run jobs as Ray tasks on the cluster at ``address`` (``"local"``: a new local instance).

    Args:
        address: Ray address (``"auto"``, ``"ray://host:10001"``, ...) or ``"local"``.
        workers: CPUs of a ``"local"`` instance (ignored when joining a cluster).

    Raises:
        RuntimeError: If Ray is not installed.
    """

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

    def run(self, function: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        ray = self._ray
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
