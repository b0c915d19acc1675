"""The project's compiled kernels: numba's ``njit``, cached on disk, with stop signals held while one compiles.

A kernel compiles on its first call with new argument types in a process (a few seconds; later
runs load it from numba's cache in ``__pycache__``). Numba calls back into Python from LLVM while
it compiles, and an exception raised there, such as the ``KeyboardInterrupt`` that ``snac-gym
evaluate`` turns a Ctrl-C or a SIGTERM into, is printed and dropped by ``ctypes``: the run would go
on as if the signal had never come. So every compile (numba's dispatcher calls
``_compile_for_args`` when no compiled version fits the arguments) runs with the stop signals (SIGINT, SIGTERM, SIGHUP,
SIGQUIT) recorded instead of handled, and a signal that came meanwhile is raised again, to the handler
that was in place, as soon as the compile returns. Calls that find a compiled version pay nothing.
"""

from __future__ import annotations

import importlib
import pickle
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Generic, ParamSpec, Protocol, TypeVar, cast

if TYPE_CHECKING:
    import numpy as np

#: The stop signals of every command (snac_gym.common._signals.STOP_SIGNALS, written again: kernels import no
#: higher layer).
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


#: The modules that define the kinematics' and the controllers' kernels.
POLICY_KERNEL_MODULES = (
    "snac_gym.kernels.chain",
    "snac_gym.kernels.small",
    "snac_gym.kernels.lqr",
    "snac_gym.kernels.hjb",
    "snac_gym.kernels.identifier",
)
#: Every module that defines a kernel (the evaluator's metrics and optimum too).
KERNEL_MODULES = (
    *POLICY_KERNEL_MODULES,
    "snac_gym.kernels.lockstep",
    "snac_gym.kernels.metrics",
    "snac_gym.kernels.trajopt",
    "snac_gym.kernels.relaxation",
)
#: The modules an evaluator's workers compile or load when they start (:func:`warm_up_shared`): all but the
#: identifier's (``snac-adaptive`` only, which a run seldom has: its workers load or compile it when called).
EVALUATOR_KERNEL_MODULES = tuple(m for m in KERNEL_MODULES if m != "snac_gym.kernels.identifier")
#: Modules the evaluator needs only in its last phase (the reference's): a worker that finds another compiling
#: one goes to work instead of waiting, and loads it from the cache when its first reference job calls it.
LATE_KERNEL_MODULES = ("snac_gym.kernels.trajopt", "snac_gym.kernels.relaxation")


def evaluator_kernel_modules(reference: bool = True) -> tuple[str, ...]:
    """The modules an evaluator's workers compile or load when they start: :data:`EVALUATOR_KERNEL_MODULES`, less the
    reference's (:data:`LATE_KERNEL_MODULES`) in a run without it. A run of the controllers alone then does not compile
    the reference's kernels (the lower bound's is the dearest compile); a controller that calls one (``mpc``'s
    Gauss-Newton steps) compiles it at its first call."""
    if reference:
        return EVALUATOR_KERNEL_MODULES
    return tuple(module for module in EVALUATOR_KERNEL_MODULES if module not in LATE_KERNEL_MODULES)


#: A module may build a kernel on first use instead of with :func:`kernel` (the lower bound's, whose helpers are
#: compiled into it): its ``lazy_kernels()`` returns (dispatcher, [example arguments, ...]) pairs for the warm-up.
_LAZY_HOOK = "lazy_kernels"
#: A kernel's example arguments (arrays, floats, ints, bools): what :func:`warm_up` calls it with.
Example = tuple[object, ...]
_Array = TypeVar("_Array", bound="np.ndarray")
_Result = TypeVar("_Result")
_Function = TypeVar("_Function", bound=Callable[..., Any])
_Parameters = ParamSpec("_Parameters")


class Lock(Protocol):
    """A lock of :func:`warm_up_shared`: ``multiprocessing``'s, a manager's, or ``threading``'s."""

    def acquire(self, block: bool = ..., /, timeout: float = ...) -> bool: ...

    def release(self) -> None: ...


_KERNELS: list[Kernel[..., Any]] = []
#: Longest wait (s) of :func:`warm_up_shared` for another process's compile of one module (a few s).
_SHARED_COMPILE_WAIT_S = 60.0


class Kernel(Generic[_Parameters, _Result]):
    """A compiled function; call it like the function (the compiled dispatcher is :attr:`dispatcher`).

    ``example`` returns arguments of the types the project calls it with, for :func:`warm_up`: one
    tuple, or a list of tuples when it is called with several (a read-only array is a type of its own).
    Type checkers see the function's signature.
    """

    def __init__(
        self,
        function: Callable[_Parameters, _Result],
        example: Callable[[], Example | list[Example]],
        warm: bool = True,
        fastmath: bool | set[str] = False,
    ) -> None:
        from numba import njit  # numba is imported by the first module that defines a kernel

        self.dispatcher = njit(cache=True, nogil=True, fastmath=fastmath)(function)
        stamp_with_dependencies(self.dispatcher)
        self.__doc__, self.__name__, self.__wrapped__ = function.__doc__, function.__name__, function
        self.example = example
        # what the dispatcher calls on a miss (numba ≥ 0.50); private, so not in numba's types
        compile_for_args = self.dispatcher._compile_for_args  # type: ignore[attr-defined]
        self.dispatcher._compile_for_args = lambda *args, **kwargs: _with_stop_signals_held(  # type: ignore[attr-defined]
            compile_for_args, args, kwargs
        )
        if warm:
            _KERNELS.append(self)

    if TYPE_CHECKING:  # the function's signature; the project calls its kernels with positional arguments only

        def __call__(self, *args: _Parameters.args, **kwargs: _Parameters.kwargs) -> _Result: ...

    else:

        def __call__(self, *args: Any) -> Any:  # no **kwargs to pass on: ~25 ns less a call, each control step
            return self.dispatcher(*args)


def kernel(
    example: Callable[[], Example | list[Example]], warm: bool = True, fastmath: bool | set[str] = False
) -> Callable[[Callable[_Parameters, _Result]], Kernel[_Parameters, _Result]]:
    """Decorator: the function compiled by numba (``nopython``, cached, releasing the GIL), see the module docstring.

    Args:
        example: Returns arguments of the types it is called with (small arrays), for :func:`warm_up`
            (a list of such tuples for several).
        warm: Compiled by :func:`warm_up` with its module's kernels. ``False`` for a kernel that no controller,
            rollout or reference calls (a public helper kept for its users): it compiles on its first call instead
            of in every cold run's warm-up.
        fastmath: numba's ``fastmath`` flags (``{"contract"}``: ``a + b*c`` may be one fused multiply-add).
    """
    return lambda function: Kernel(function, example, warm, fastmath)


def helper(function: _Function, fastmath: bool | set[str] = False, inline: bool = False) -> _Function:
    """``function`` compiled by numba (``nopython``, cached, releasing the GIL) for compiled callers only: no CPython
    or C wrapper is built for it (a tenth of a second or more of a cold run's compile each), so Python cannot call
    it.

    ``inline``: inlined into its callers by numba instead (``inline="always"``), for a thin layer between two large
    functions: compiled on its own, its library is optimised and emitted again with everything it calls."""
    from numba import njit  # numba is imported by the first module that defines a kernel

    options: dict[str, Any] = {"cache": True, "nogil": True, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}
    if inline:
        options["inline"] = "always"
    return cast("_Function", njit(**options, fastmath=fastmath)(function))


def read_only(array: _Array) -> _Array:
    """``array`` marked read-only, for an ``example``: numba compiles a read-only array as a type of its own
    (the kinematics' cached Jacobians are read-only), so a kernel called with both needs both examples."""
    array.setflags(write=False)
    return array


def read_only_view(array: object) -> np.ndarray:
    """``array`` as a C-contiguous float64 array that numba types as read-only (a view, not a copy, where it
    already is one): a kernel that reads a stack (Jacobians, matrices) is called with read-only arrays only, the
    kinematics' cached ones and any other alike, so that it compiles one signature, not two (each is seconds of a
    cold run's compiles)."""
    import numpy as np  # the caller's numpy: this module imports it only here and for type checkers

    out = np.ascontiguousarray(array, dtype=float)
    if out.flags.writeable:
        out = out.view()
        out.setflags(write=False)
    return out


def warm_up(modules: tuple[str, ...] = KERNEL_MODULES) -> float:
    """Compile, or load from the cache, every kernel of ``modules`` now; the seconds it took.

    A loop with a deadline calls this first (``snac-gym real``): a kernel's first call takes a
    tenth of a second to load from the cache and seconds to compile, far beyond one control period.
    """
    started = time.perf_counter()
    lazy = []
    for module in modules:
        lazy += _lazy_kernels(importlib.import_module(module))
    for compiled in _KERNELS:
        if compiled.__wrapped__.__module__ in modules:
            examples = compiled.example()
            for arguments in examples if isinstance(examples, list) else [examples]:
                compiled(*arguments)
    for dispatcher, examples in lazy:
        for arguments in examples:
            _with_stop_signals_held(dispatcher, arguments)
    return time.perf_counter() - started


def _lazy_kernels(module: ModuleType) -> list[tuple[Any, list[Example]]]:  # Any: a numba dispatcher
    hook = getattr(module, _LAZY_HOOK, None)
    return list(hook()) if hook is not None else []


def cached_on_disk(modules: tuple[str, ...] = KERNEL_MODULES) -> bool:
    """Whether every kernel of ``modules`` has a numba cache index that numba takes as up to date.

    Then :func:`warm_up` only loads (a tenth of a second a module) instead of compiling (seconds).
    The index is the one numba itself reads (its cache folder and file name, for this Python);
    a cache this misjudges costs time only, as numba checks each index and compiles what is out of
    date. Says no where numba's cache layout is not the one known here.
    """
    dispatchers = []
    for module in modules:
        dispatchers += [dispatcher for dispatcher, _ in _lazy_kernels(importlib.import_module(module))]
    dispatchers += [compiled.dispatcher for compiled in _KERNELS if compiled.__wrapped__.__module__ in modules]
    for dispatcher in dispatchers:
        cache = dispatcher._cache  # numba's FunctionCache (njit(cache=True))
        try:
            index = Path(cache._cache_path) / f"{cache._impl.filename_base}.nbi"
            source = Path(cache._impl.locator._py_file)
        except AttributeError:  # another numba's internals
            return False
        if not index.is_file():
            return False
        # numba's own test where its index can be read: the stamp it was written for against the source's now (a
        # hash of the source in numba 0.68: a file touched but not changed, a checkout there and back, stays cached)
        stamp = _index_stamp(index)
        if stamp is None:
            stale = index.stat().st_mtime < source.stat().st_mtime
        else:  # numba's own test, its helpers' modules' stamps included (stamp_with_dependencies)
            try:
                stale = stamp != _source_stamp(dispatcher)
            except AttributeError:  # another numba's internals
                return False
        if stale:
            return False
    return True


def stamp_with_dependencies(dispatcher: Any) -> None:
    """Key ``dispatcher``'s numba cache on the source of every module whose compiled helpers it calls, not its own
    alone.

    Numba stamps a cached function's index with its own source file and loads the machine code while that file is
    unchanged: a kernel that calls (or inlines) a helper of another module, such as the reference's curvature kernel
    calling the chain's ``joint_frames`` or the LQR's calling ``jacobi_eigh``, would keep running the old helper
    after that module changed, an update or an edit (tests/kernels/test_compiled.py). The helpers are found through
    the names the function reads, and theirs in turn. Where numba's cache is not laid out as known here, nothing is
    changed.
    """
    try:
        dispatcher._cache._cache_file._source_stamp = _source_stamp(dispatcher)
    except AttributeError:  # no cache, or another numba's internals
        return


def _source_stamp(dispatcher: Any) -> object:
    """The stamp of ``dispatcher``'s source as its cache index holds it: numba's own, with the stamps of the other
    modules whose helpers it calls where there are any (:func:`stamp_with_dependencies`), as they are now.

    Raises:
        AttributeError: Where numba's cache is not laid out as known here.
    """
    own = dispatcher._cache._impl.locator.get_source_stamp()
    stamps, seen, pending = {}, set(), [dispatcher.py_func]
    while pending:
        function = pending.pop()
        for name in function.__code__.co_names:
            helper_dispatcher = function.__globals__.get(name)
            called = getattr(helper_dispatcher, "py_func", None)
            if called is None or called in seen:
                continue
            seen.add(called)
            pending.append(called)
            if called.__module__ != dispatcher.py_func.__module__:
                stamps[called.__module__] = helper_dispatcher._cache._impl.locator.get_source_stamp()
    return (own, tuple(sorted(stamps.items()))) if stamps else own


def _index_stamp(index: Path) -> object | None:
    """The source stamp a numba cache index was written for (numba's format: a pickled version, then the pickled
    ``(stamp, overloads)``), or None where it cannot be read so."""
    stamp: object
    try:
        with index.open("rb") as file:
            pickle.load(file)  # numba's version
            stamp, _ = pickle.loads(file.read())
    except Exception:  # noqa: BLE001 - another numba's format: the caller falls back to the files' times
        return None
    return stamp


def load_if_cached(modules: tuple[str, ...] = KERNEL_MODULES) -> bool:
    """:func:`warm_up` of ``modules`` only where it loads every kernel from the cache (:func:`cached_on_disk`);
    whether it did. A process that forks workers calls it so that they inherit the kernels; a kernel
    still to compile is left to them, as they share the compiles (:func:`warm_up_shared`)."""
    if not cached_on_disk(modules):
        return False
    warm_up(modules)
    return True


def warm_up_shared(locks: Sequence[Lock], modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES) -> list[str]:
    """:func:`warm_up` of ``modules`` in processes that share the compiles; the modules whose lock this one took.

    ``locks`` holds one ``multiprocessing`` lock per module, the same for every process. A process
    takes each lock it finds free and compiles (or loads) that module's kernels while it holds
    it; it then waits for each module another process held, and loads that from the cache the
    other wrote. On a fresh install, where every kernel compiles, two evaluator workers made the
    same compiles at once (the run's first phase 5-8 s longer); now each compile happens once.
    The dearest compile (the lower bound's) is taken first, and a module of :data:`LATE_KERNEL_MODULES`
    held by another process is not waited for: the worker that compiles the rest starts the passes while
    the other still compiles the reference's kernels.

    Raises:
        ValueError: If there is not one lock per module.
    """
    if len(locks) != len(modules):
        raise ValueError(f"need one lock per module ({len(modules)}), got {len(locks)}")
    taken, waiting = [], []
    # The dearest compile first (the lower bound's, last in KERNEL_MODULES): the first worker takes it while the
    # other compiles the rest, instead of both walking the modules in one order, each compile after the last.
    for module, lock in reversed(list(zip(modules, locks, strict=True))):
        if lock.acquire(False):  # not blocking (multiprocessing and threading locks alike)
            try:
                warm_up((module,))
            finally:
                lock.release()
            taken.append(module)
        elif module not in LATE_KERNEL_MODULES:
            waiting.append((module, lock))
    for module, lock in waiting:
        # Released once the process holding it has written the module's cache; a process that died
        # holding it never releases it, and this one then compiles the module itself.
        got = lock.acquire(timeout=_SHARED_COMPILE_WAIT_S)
        try:
            warm_up((module,))
        finally:
            if got:
                lock.release()
    return taken


@contextmanager
def on_first_compile(callback: Callable[[], object]) -> Iterator[None]:
    """Within the block, ``callback()`` once, as the first compile of a kernel in this process starts: numba's own
    compile event, which a load from its cache does not send, so a run whose kernels are all cached says nothing.

    A command that compiles as it goes (``snac-gym demo``) says why its first seconds are silent. Where numba has
    no event API (another version), nothing is called.
    """
    try:
        from numba.core import event  # numba is imported by the first module that defines a kernel
    except ImportError:  # another numba: no announcement, the run is the same
        yield
        return
    pending = [callback]

    class _First(event.Listener):
        def on_start(self, event: object) -> None:  # noqa: ARG002 - numba's signature
            if pending:
                pending.pop()()

        def on_end(self, event: object) -> None:  # noqa: ARG002 - numba's signature
            pass

    with event.install_listener("numba:compile", _First()):
        yield


def _with_stop_signals_held(
    function: Callable[..., _Result], args: tuple[object, ...], kwargs: dict[str, object] | None = None
) -> _Result:
    """``function(*args, **kwargs)`` with the stop signals recorded, then each one received raised again."""
    kwargs = kwargs or {}
    if threading.current_thread() is not threading.main_thread():  # handlers run, and are set, in the main thread only
        return function(*args, **kwargs)
    received: list[int] = []
    signum: int  # the loops' variable below: a Signals member, then a received signal's number
    previous = {
        signum: signal.signal(signum, lambda signum, frame: received.append(signum)) for signum in _STOP_SIGNALS
    }
    try:
        return function(*args, **kwargs)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)  # None: set outside Python
        # Each signal received, once, in order: a worker ignores SIGINT but must still die of the
        # SIGTERM that came after it; where a handler raises, the first one raised ends this loop.
        for signum in dict.fromkeys(received):
            signal.raise_signal(signum)


__all__ = [
    "EVALUATOR_KERNEL_MODULES", "KERNEL_MODULES", "LATE_KERNEL_MODULES", "POLICY_KERNEL_MODULES", "Example", "Kernel",
    "cached_on_disk", "evaluator_kernel_modules", "helper", "kernel", "load_if_cached", "on_first_compile", "read_only",
    "read_only_view", "warm_up", "warm_up_shared",
]  # fmt: skip
