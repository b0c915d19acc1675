"""The real-time loop's measures: each applied and undone, or refused with one line that says why."""

from __future__ import annotations

import gc
import os
import resource

import pytest

from snac_gym.real import loop_tuning
from snac_gym.real.loop_tuning import LoopTuning, frozen_gc, tuned_process


def test_sched_fifo_not_permitted_is_one_line_and_the_run_goes_on(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    before = os.sched_getscheduler(0)
    with tuned_process(LoopTuning(rt_priority=20)) as notes:
        assert notes == [
            "SCHED_FIFO priority 20 not permitted (needs root, CAP_SYS_NICE or an rtprio limit): "
            "the loop runs at normal priority"
        ]
        assert os.sched_getscheduler(0) == before


def test_memory_is_not_locked_under_a_small_memlock_limit(monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    monkeypatch.setattr(resource, "getrlimit", lambda _: (8 << 20, 8 << 20))
    locked = []
    monkeypatch.setattr(loop_tuning, "unlock_memory", lambda: locked.append("unlocked"))
    with tuned_process(LoopTuning(lock_memory=True)) as notes:
        assert notes == [
            "memory not locked: RLIMIT_MEMLOCK is 8192 KiB (needs unlimited, or CAP_IPC_LOCK): "
            "pages may fault during the loop"
        ]
    assert locked == []  # nothing was locked, so nothing is unlocked


@pytest.mark.skipif(os.geteuid() != 0, reason="needs the right to set SCHED_FIFO")
def test_sched_fifo_is_set_for_the_block_and_restored_after():
    before = os.sched_getscheduler(0)
    with tuned_process(LoopTuning(rt_priority=1)) as notes:
        assert notes == [] and os.sched_getscheduler(0) == os.SCHED_FIFO
    assert os.sched_getscheduler(0) == before


def test_the_collector_is_frozen_and_off_for_the_episode_and_restored_after():
    assert gc.isenabled()
    with frozen_gc(True):
        assert not gc.isenabled() and gc.get_freeze_count() > 0
    assert gc.isenabled() and gc.get_freeze_count() == 0
    with frozen_gc(False):
        assert gc.isenabled()


def test_the_cli_option_turns_every_measure_on_and_bad_priorities_are_refused():
    assert LoopTuning.realtime(20) == LoopTuning(rt_priority=20, lock_memory=True, freeze_gc=True)
    assert LoopTuning.realtime(0) == LoopTuning()
    with pytest.raises(ValueError, match=r"rt_priority must be a whole number in \[0, 99\], got 100"):
        LoopTuning(rt_priority=100)
