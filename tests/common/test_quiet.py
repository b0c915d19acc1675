"""``quiet_output`` under a stop signal: wherever in its swaps of descriptors 1 and 2 the signal comes, both come back
and the signal still ends the block, so that the command's one line about it reaches the terminal."""

from __future__ import annotations

import subprocess
import sys

import pytest

#: In a child process (it sets signal handlers and moves descriptors 1 and 2): the n-th call of ``os.dup``,
#: ``os.dup2``, ``os.open`` or ``os.close`` made by quiet_output raises SIGTERM right after it returns, under the
#: commands' handler. Prints how the block ended, then writes to both descriptors.
DRIVER = r"""
import os, signal, sys, time
from snac_gym.common import _quiet
from snac_gym.common._signals import TerminationSignal, stop_signals_raise

target = int(sys.argv[1])
calls = []
inode = {fd: os.fstat(fd).st_ino for fd in (1, 2)}
open_before = len(os.listdir("/proc/self/fd"))


class SignalAfterCall:
    def __getattr__(self, name):
        function = getattr(os, name)
        if name not in ("dup", "dup2", "open", "close"):
            return function

        def called(*args):
            result = function(*args)
            calls.append(name)
            if len(calls) == target:
                signal.raise_signal(signal.SIGTERM)
            return result

        return called


_quiet.os = SignalAfterCall()
ended = "not interrupted"
with stop_signals_raise():
    try:
        with _quiet.quiet_output():
            os.write(1, b"silenced\n")
        time.sleep(1.0)  # a signal sent again arrives within a millisecond or so
    except TerminationSignal as exc:
        ended = exc.signal_name
restored = all(os.fstat(fd).st_ino == inode[fd] for fd in (1, 2))
leaked = len(os.listdir("/proc/self/fd")) - open_before
os.write(2, f"interrupted by {ended}; calls {len(calls)}; restored {restored}; leaked {leaked}\n".encode())
os.write(1, b"stdout still here\n")
"""

#: quiet_output's calls: dup 1, dup 2, open /dev/null, dup2 onto 1 and 2, dup2 back onto 1 and 2, three closes.
CALLS = 10


@pytest.mark.parametrize("call", range(1, CALLS + 1))
def test_a_stop_signal_anywhere_in_the_swaps_leaves_both_descriptors_restored_and_still_ends_the_block(call):
    done = subprocess.run([sys.executable, "-c", DRIVER, str(call)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stderr == f"interrupted by SIGTERM; calls {CALLS}; restored True; leaked 0\n"
    assert done.stdout == "stdout still here\n"  # and "silenced" went to /dev/null


def test_without_a_signal_the_block_runs_through_and_closes_what_it_opened():
    done = subprocess.run([sys.executable, "-c", DRIVER, "0"], capture_output=True, text=True, timeout=60)
    assert done.stderr == f"interrupted by not interrupted; calls {CALLS}; restored True; leaked 0\n"
    assert done.stdout == "stdout still here\n"


#: In a child process: SIGTERM sent as ``__exit__`` is called, so that it is pending at that method's first
#: instruction, where the handler runs (as a signal that came during a slow C call in the block is handled).
AT_EXIT = r"""
import os, signal, sys, time
from snac_gym.common._quiet import quiet_output
from snac_gym.common._signals import TerminationSignal, stop_signals_raise

armed = []


def profile(frame, event, arg):
    if armed and event == "call" and frame.f_code.co_name == "__exit__":
        armed.clear()
        os.kill(os.getpid(), signal.SIGTERM)


def silenced(fd):
    null, now = os.stat(os.devnull), os.fstat(fd)
    return (now.st_dev, now.st_ino) == (null.st_dev, null.st_ino)


ended, state = "not interrupted", None
with stop_signals_raise():
    try:
        with quiet_output():
            armed.append(True)
            sys.setprofile(profile)
        sys.setprofile(None)
        time.sleep(1.0)  # a signal sent again arrives within a millisecond or so
    except TerminationSignal as exc:  # where a command says which signal ended it, the traceback still alive
        sys.setprofile(None)
        ended, state = exc.signal_name, (silenced(1), silenced(2))
os.write(2, f"interrupted by {ended}; silenced then {state}\n".encode())
"""


def test_a_stop_signal_handled_as_the_block_exits_still_gives_both_descriptors_back():
    """With a generator-based context manager the handler raised at the first instruction of contextlib's
    ``__exit__``, the generator's ``finally`` did not run, and the command's line about the signal went to
    ``/dev/null`` (seen when ``demo`` was stopped as PyBullet connected, right after its import)."""
    done = subprocess.run([sys.executable, "-c", AT_EXIT], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "interrupted by SIGTERM; silenced then (False, False)\n"
