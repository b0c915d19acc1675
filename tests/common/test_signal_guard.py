"""``stop_signals_raise`` under a stop signal that comes while it sets or puts back its handlers: whenever it comes,
every handler ends as it was before the block and the signal still raises, once (the nested form ``snac-gym real``
uses inside the command's own guard)."""

from __future__ import annotations

import subprocess
import sys

import pytest

#: In a child process: the command's guard is installed, as ``main()`` installs it; then the n-th ``signal.signal``
#: call made by ``stop_signals_raise`` (four to set, four to put back) raises SIGTERM right after it returns.
DRIVER = r"""
import signal, sys, time
from snac_gym.common import _signals
from snac_gym.common._signals import STOP_SIGNALS, SignalGuard, TerminationSignal, stop_signals_raise

outer = SignalGuard()
outer.install(STOP_SIGNALS)
target = int(sys.argv[1])
calls = []


class SignalAfterSet:
    def __getattr__(self, name):
        return getattr(signal, name)

    @staticmethod
    def signal(signum, handler):
        replaced = signal.signal(signum, handler)
        calls.append(signum)
        if len(calls) == target:
            signal.raise_signal(signal.SIGTERM)
        return replaced


_signals.signal = SignalAfterSet()
raised = []
try:
    with stop_signals_raise():
        time.sleep(0.5)  # a signal sent again arrives within a millisecond or so
    time.sleep(0.5)
except TerminationSignal as exc:
    raised.append(exc.signal_name)
_signals.signal = signal
restored = all(signal.getsignal(signum) == outer.handle for signum in STOP_SIGNALS)
print(f"raised {raised}; calls {len(calls)}; handlers restored {restored}")
"""


@pytest.mark.parametrize("call", range(1, 9))
def test_a_stop_signal_while_the_handlers_are_set_or_put_back_raises_once_and_every_handler_comes_back(call):
    done = subprocess.run([sys.executable, "-c", DRIVER, str(call)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "raised ['SIGTERM']; calls 8; handlers restored True\n"


def test_without_a_signal_the_block_runs_through_and_puts_every_handler_back():
    done = subprocess.run([sys.executable, "-c", DRIVER, "0"], capture_output=True, text=True, timeout=60)
    assert done.stdout == "raised []; calls 8; handlers restored True\n", done.stderr


#: In a child process: a module whose own code sends SIGTERM, then calls on while the handler runs (at the call's
#: return), as ``torch.distributed``'s does when its C++ initialisation takes the signal.
IMPORTED = r"""
import os, signal, sys, time
os.kill(os.getpid(), signal.SIGTERM)
sum(range(200_000))
time.sleep(0.05)
DONE = True
"""
IMPORTER = r"""
import sys, time
from snac_gym.common._signals import TerminationSignal, stop_signals_raise
sys.path.insert(0, sys.argv[1])
try:
    with stop_signals_raise():
        import signalled_at_import
        time.sleep(2)
    print("not raised")
except TerminationSignal as exc:  # wherever it was raised after the import, the module is whole
    module = sys.modules.get("signalled_at_import")
    print("raised", exc.signal_name, "with the module imported whole:", getattr(module, "DONE", False))
"""


def test_a_stop_signal_during_an_import_raises_once_the_import_has_run_whole(tmp_path):
    """Raised inside a module's import, the interrupt can come out of C++ that cannot pass it on (the process
    aborts: ``terminate called after throwing an instance of 'pybind11::error_already_set'``, seen when
    ``train-ppo`` was stopped while torch imported); it is sent again and raised after the import."""
    (tmp_path / "signalled_at_import.py").write_text(IMPORTED)
    done = subprocess.run([sys.executable, "-c", IMPORTER, str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "raised SIGTERM with the module imported whole: True\n", done.stderr
