"""Stop signals: one set for every command, handlers that raise once, and never lost where Python cannot raise.

Every ``snac-gym`` command ends the same way on :data:`STOP_SIGNALS` (SIGINT, SIGTERM, SIGHUP,
SIGQUIT): :func:`stop_signals_raise` turns the first into :class:`TerminationSignal` (a
``KeyboardInterrupt``, so that every clean-up written for Ctrl-C runs for the others too), the
command says in one line what it kept, and the process exits 128 + the signal's number
(:func:`exit_code`). A second signal only is recorded: it must not cut the clean-up the first one
started.

A handler runs in the main thread at whatever Python code runs there when the signal comes, and
some code cannot take an exception:

* a ``__del__``, which the garbage collector may run at any point (numba's LLVM objects have one):
  an exception raised there is printed ("Exception ignored in ...") and dropped, so the interrupt
  would be lost, the run would go on, and a handler that raises only for the first signal would
  never raise;
* numba's own Python code, which its compiled code and dispatchers call back (``_numba_unpickle``
  when a cached kernel first runs, the compiler): an exception raised there surfaces as a
  ``SystemError`` with a traceback instead of the interrupt;
* an import made by a C extension's initialisation (mujoco's pybind11 modules import each other): the
  extension turns the interrupt into ``ImportError("initialization failed")``, which a caller that
  treats a failed import as a missing optional package would take for one, and the run would go on;
* the code of a module being imported: a C++ extension's functions that module code calls at import (torch's
  ``torch._C._c10d_init()`` when ``torch.distributed`` is imported) may run the handler from C++ that cannot pass an
  exception on, and the process aborts with ``terminate called after throwing an instance of
  'pybind11::error_already_set'`` instead of exiting on the signal; and an interrupt raised in an import leaves a
  half-imported package behind for the clean-up to meet;
* a few lines that change process state in steps (:func:`uninterruptible`): an exception between two steps leaves
  it half changed (``quiet_output`` with descriptor 1 given back and 2 still on ``/dev/null``, so that the
  command's one line about the signal went nowhere).

So a handler that finds itself in such code sends the signal again, to be handled once that code
has returned (numba's Python code runs only while a kernel is dispatched or compiled, never while
one computes; an import ends when its modules' code has run, about a second for torch, the largest here).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
import types
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, ParamSpec, TypeVar, cast

#: The signals every command ends on: Ctrl-C, a scheduler's or ``kill``'s SIGTERM, a closed
#: terminal's SIGHUP and Ctrl-\\'s SIGQUIT (whose default would dump core). SIGKILL cannot be caught.
STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)

#: Packages whose Python code is called back from compiled code, where an exception cannot propagate.
_CALLED_BACK = ("numba", "llvmlite")
#: The code of the functions :func:`uninterruptible` marks.
_UNINTERRUPTIBLE: set[types.CodeType] = set()
_P = ParamSpec("_P")
_R = TypeVar("_R")
if TYPE_CHECKING:  # sys.UnraisableHookArgs is the stubs' name only
    #: What ``signal.signal`` returns: the handler it replaced (a function, SIG_DFL/SIG_IGN, None: set outside Python).
    Handler = Callable[[int, types.FrameType | None], object] | int | signal.Handlers | None
    #: A ``sys.unraisablehook``.
    UnraisableHook = Callable[[sys.UnraisableHookArgs], object]


def uninterruptible(function: Callable[_P, _R]) -> Callable[_P, _R]:
    """Mark ``function`` as one a stop signal's exception must not cut: a signal that comes while it (or what it
    calls) runs is sent again, and raises once it has returned. For a few lines that change process state in steps,
    each of which must be undone or all made (a caller's ``finally`` runs only once the function has returned)."""
    _UNINTERRUPTIBLE.add(function.__code__)
    return function


def cannot_raise_here(frame: types.FrameType | None) -> bool:
    """Whether ``frame`` (a handler's second argument) runs inside a ``__del__``, numba's own code, a C
    extension's initialisation, a module's import or an :func:`uninterruptible` function."""
    while frame is not None:
        if frame.f_code.co_name == "__del__" or frame.f_code in _UNINTERRUPTIBLE or _in_extension_init(frame):
            return True
        if _in_module_import(frame):
            return True
        module = frame.f_globals.get("__name__") or ""
        if module.partition(".")[0] in _CALLED_BACK:
            return True
        frame = frame.f_back
    return False


def _in_module_import(frame: types.FrameType) -> bool:
    # importlib marks a module's spec while its code runs (_load_unlocked); a script's __main__ has no such mark
    if frame.f_code.co_name != "<module>":
        return False
    return bool(getattr(frame.f_globals.get("__spec__"), "_initializing", False))


def _in_extension_init(frame: types.FrameType) -> bool:
    # importlib runs an extension's init from the loader's own methods; only their frames name the loader
    if frame.f_code.co_name not in ("exec_module", "create_module"):
        return False
    loader = frame.f_locals.get("self")
    return type(loader).__name__ == "ExtensionFileLoader"


def interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt ``exc`` was raised in place of (its cause or context, at any depth), if any: code that
    converts every exception it meets (a C extension's init) hides one behind its own."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def send_again(signum: int, delay: float = 0.001) -> None:
    """Send ``signum`` to this process again after ``delay`` seconds, from a helper thread."""

    def send() -> None:
        time.sleep(delay)
        os.kill(os.getpid(), signum)

    threading.Thread(target=send, name=f"resend-signal-{signum}", daemon=True).start()


class TerminationSignal(KeyboardInterrupt):
    """A stop signal received while :func:`stop_signals_raise` was in force.

    A ``KeyboardInterrupt``, so that everything that cleans up on Ctrl-C does the same for the others.
    """

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.signal_name = signal.Signals(signum).name
        super().__init__(self.signal_name)


class SignalGuard:
    """What :func:`stop_signals_raise` yields: the signals received, and whether they still raise.

    Only the first signal raises: a second one (an impatient operator, a supervisor that sends
    SIGTERM then SIGQUIT) must not cut the clean-up the first started. After :meth:`defer`,
    signals are only recorded; :meth:`raise_pending` raises the first one then.
    """

    def __init__(self) -> None:
        self.received: list[int] = []
        self.deferred = False
        self._in_hook = 0  # > 0 while the unraisable hook runs

    def handle(self, signum: int, frame: types.FrameType | None) -> None:
        # Raised in a __del__, numba's code or the unraisable hook itself, it would be dropped (or a SystemError):
        # the hook's own resend can arrive while the hook still runs (seen on Python 3.13 under load).
        if self._in_hook or cannot_raise_here(frame):
            send_again(signum)
            return
        self.received.append(signum)
        if len(self.received) == 1 and not self.deferred:
            raise TerminationSignal(signum)

    def defer(self) -> None:
        self.deferred = True

    def resume(self) -> None:
        """Let signals raise again after :meth:`defer`: one held meanwhile raises now, a later first one when it
        comes (what was deferred is written; what follows may be cut, such as a finished run's figures)."""
        self.deferred = False
        self.raise_pending()

    def unraisable(self, unraisable: sys.UnraisableHookArgs, previous: UnraisableHook) -> None:
        """``sys.unraisablehook`` while the guard holds: an interrupt raised where Python drops exceptions
        (a weakref or garbage-collector callback, code called back from C, none of which
        :func:`cannot_raise_here` sees) is sent again instead of being lost."""
        if isinstance(unraisable.exc_value, TerminationSignal) and not self.deferred:
            if self.received:
                self.received.pop()  # not delivered: the signal sent again raises in its place
            send_again(unraisable.exc_value.signum)
            return
        previous(unraisable)

    @uninterruptible
    def install(
        self, signals: Sequence[int] = STOP_SIGNALS, replaced: dict[int, Handler] | None = None
    ) -> tuple[dict[int, Handler], UnraisableHook]:
        """Set the handlers of ``signals`` and the unraisable hook; return what they replaced (each handler also
        recorded in ``replaced`` as it is set). A signal that comes meanwhile raises once all are set."""
        handlers = {} if replaced is None else replaced
        for signum in signals:
            handlers[signum] = signal.signal(signum, self.handle)
        hook = sys.unraisablehook

        def guarded_hook(unraisable: sys.UnraisableHookArgs) -> None:
            self._in_hook += 1
            try:
                self.unraisable(unraisable, hook)
            finally:
                self._in_hook -= 1

        sys.unraisablehook = guarded_hook
        return handlers, hook

    def raise_pending(self) -> None:
        if self.received:
            raise TerminationSignal(self.received[0])

    def signal_name(self, exc: BaseException | None = None) -> str:
        """The name of the signal that ended the run: ``exc``'s own, else the first received, else SIGINT
        (a library between the handler and the caller, such as Ray's client, may raise its own
        ``KeyboardInterrupt`` without the name)."""
        name = getattr(exc, "signal_name", None)
        if name is None and self.received:
            name = signal.Signals(self.received[0]).name
        return cast(str, name) if name in signal.Signals.__members__ else "SIGINT"  # a member's name: a str


@contextmanager
def stop_signals_raise(signals: Sequence[int] = STOP_SIGNALS) -> Iterator[SignalGuard]:
    """Within the block, the first of ``signals`` raises :class:`TerminationSignal`; the handlers before are restored
    after.

    SIGINT is included because a process started from a background shell inherits it ignored.
    Handlers can only be set from the main thread; elsewhere the block runs unchanged.
    """
    guard = SignalGuard()
    if threading.current_thread() is not threading.main_thread():
        yield guard
        return
    replaced: dict[int, Handler] = {}
    hook = sys.unraisablehook
    try:
        guard.install(signals, replaced)
        yield guard
    finally:
        _restore(replaced, hook)


@uninterruptible
def _restore(handlers: dict[int, Handler], hook: UnraisableHook) -> None:
    """Put back the handlers and the unraisable hook :meth:`SignalGuard.install` replaced; a signal that comes meanwhile
    goes to the handler put back, once all are."""
    sys.unraisablehook = hook
    for signum, handler in handlers.items():
        signal.signal(signum, handler if handler is not None else signal.SIG_DFL)  # None: set outside Python


def exit_code(signal_name: str) -> int:
    """The exit status of a process ended by ``signal_name``, as a shell reports it: 128 + its number."""
    return 128 + int(signal.Signals[signal_name])
