"""Stop-signal handlers that raise, without losing the signal to a finaliser.

A handler runs in the main thread at whatever Python code runs there when the signal comes, and the
garbage collector may be running a ``__del__`` at that moment (numba's LLVM objects have them). An
exception raised inside a ``__del__`` is printed ("Exception ignored in ...") and dropped: the
interrupt would be lost, the run would go on, and a handler that raises only for the first signal
would then never raise. So a handler that finds itself inside a finaliser sends the signal again,
to be handled once the finaliser has returned.
"""

from __future__ import annotations

import os
import threading
import time
import types


def inside_finaliser(frame: types.FrameType | None) -> bool:
    """Whether ``frame`` (a handler's second argument) runs inside a ``__del__``."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def send_again(signum: int, delay: float = 0.001) -> None:
    """Send ``signum`` to this process again after ``delay`` seconds, from a helper thread."""

    def send() -> None:
        time.sleep(delay)
        os.kill(os.getpid(), signum)

    threading.Thread(target=send, name=f"resend-signal-{signum}", daemon=True).start()
