"""Stop-signal handlers that raise, without losing the signal where Python cannot raise it.

A handler runs in the main thread at whatever Python code runs there when the signal comes, and
some code cannot take an exception:

* a ``__del__``, which the garbage collector may run at any point (numba's LLVM objects have one):
  an exception raised there is printed ("Exception ignored in ...") and dropped, so the interrupt
  would be lost, the run would go on, and a handler that raises only for the first signal would
  never raise;
* numba's own Python code, which its compiled code and dispatchers call back (``_numba_unpickle``
  when a cached kernel first runs, the compiler): an exception raised there surfaces as a
  ``SystemError`` with a traceback instead of the interrupt.

So a handler that finds itself in such code sends the signal again, to be handled once that code
has returned (numba's Python code runs only while a kernel is dispatched or compiled, never while
one computes).
"""

from __future__ import annotations

import os
import threading
import time
import types

#: Packages whose Python code is called back from compiled code, where an exception cannot propagate.
_CALLED_BACK = ("numba", "llvmlite")


def cannot_raise_here(frame: types.FrameType | None) -> bool:
    """Whether ``frame`` (a handler's second argument) runs inside a ``__del__`` or numba's own code."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        module = frame.f_globals.get("__name__") or ""
        if module.partition(".")[0] in _CALLED_BACK:
            return True
        frame = frame.f_back
    return False


def send_again(signum: int, delay: float = 0.001) -> None:
    """Send ``signum`` to this process again after ``delay`` seconds, from a helper thread."""

    def send() -> None:
        time.sleep(delay)
        os.kill(os.getpid(), signum)

    threading.Thread(target=send, name=f"resend-signal-{signum}", daemon=True).start()
