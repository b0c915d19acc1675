"""What makes the host's control loop as deterministic as CPython allows, each part switchable.

* ``rt_priority``: the loop's thread (and the ur_rtde client process started after it, which
  inherits it) under ``SCHED_FIFO``: a CPU hog beside it does not delay the loop's wake-ups.
  Needs root or ``CAP_SYS_NICE`` (or an ``rtprio`` limit in ``/etc/security/limits.conf``);
  where it is not permitted the run goes on at normal priority and says so.
* ``lock_memory``: ``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page of the process is paged out
  or faulted in lazily during the episode. Needs ``CAP_IPC_LOCK`` or a large enough
  ``RLIMIT_MEMLOCK``; not permitted, it is skipped with a message (never half-applied: a
  future-pages lock under a small limit would make later allocations fail).
* ``freeze_gc``: ``gc.freeze()`` then ``gc.disable()`` for the episode: no collection pass
  (milliseconds with a large heap) can land in a period; reference counting still frees
  what the loop drops. Restored after the episode.

The stream log's writing off the loop thread is :class:`~snac_gym.real.journal.StepJournal`'s
(``writer="process"``, the default). ``docs/scripts/loop_determinism.py`` measures each part on
and off at 500 Hz (docs/hardware-in-the-loop.md).
"""

from __future__ import annotations

import ctypes
import gc
import os
import resource
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from snac_gym.real.safety import check_whole_in

_MCL_CURRENT, _MCL_FUTURE = 1, 2


@dataclass(frozen=True)
class LoopTuning:
    """The parts of :mod:`snac_gym.real.loop_tuning` to apply for a real run (all off by default).

    Attributes:
        rt_priority: ``SCHED_FIFO`` priority of the control loop, in [0, 99] (0: normal scheduling).
        lock_memory: Lock the process's memory (``mlockall``).
        freeze_gc: Freeze and disable the garbage collector during the episode.
    """

    rt_priority: int = 0
    lock_memory: bool = False
    freeze_gc: bool = False

    def __post_init__(self) -> None:
        check_whole_in("rt_priority", self.rt_priority, 0, 99)

    @classmethod
    def realtime(cls, rt_priority: int) -> LoopTuning:
        """Every part on (``rt_priority`` > 0), none with 0: what ``snac-gym real --rt-priority N`` applies."""
        on = rt_priority > 0
        return cls(rt_priority=rt_priority, lock_memory=on, freeze_gc=on)


def set_fifo_priority(priority: int) -> str | None:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority``; a one-line reason if not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return (
            f"SCHED_FIFO priority {priority} not permitted (needs root, CAP_SYS_NICE or an rtprio limit): "
            "the loop runs at normal priority"
        )
    except (OSError, AttributeError) as exc:
        return f"SCHED_FIFO not available here ({exc}): the loop runs at normal priority"
    return None


def lock_memory() -> str | None:
    """``mlockall`` of current and future pages; a one-line reason if not permitted (nothing locked then)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if os.geteuid() != 0 and soft != resource.RLIM_INFINITY:
        return (
            f"memory not locked: RLIMIT_MEMLOCK is {soft // 1024} KiB (needs unlimited, or CAP_IPC_LOCK): "
            "pages may fault during the loop"
        )
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        return f"memory not locked: mlockall failed ({os.strerror(ctypes.get_errno())})"
    return None


def unlock_memory() -> None:
    ctypes.CDLL(None, use_errno=True).munlockall()


@contextmanager
def tuned_process(tuning: LoopTuning) -> Iterator[list[str]]:
    """Apply the process-wide parts (priority, memory lock) for the block; yields what could not be applied.

    Entered before the connection is made, so that the ur_rtde client process inherits the priority.
    """
    notes: list[str] = []
    previous = None
    if tuning.rt_priority:
        previous = (os.sched_getscheduler(0), os.sched_getparam(0))
        note = set_fifo_priority(tuning.rt_priority)
        if note:
            notes.append(note)
            previous = None
    locked = False
    if tuning.lock_memory:
        note = lock_memory()
        locked = note is None
        if note:
            notes.append(note)
    try:
        yield notes
    finally:
        if locked:
            unlock_memory()
        if previous is not None:
            os.sched_setscheduler(0, previous[0], previous[1])


@contextmanager
def frozen_gc(on: bool) -> Iterator[None]:
    """No garbage-collection pass within the block (``on``); the collector as it was afterwards."""
    if not on:
        yield
        return
    was_enabled = gc.isenabled()
    gc.collect()
    gc.freeze()  # what exists now is never scanned again: the episode's own garbage stays small
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if was_enabled:
            gc.enable()
