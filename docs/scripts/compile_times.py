"""Where a cold compile's time goes: every kernel module compiled in turn in this process, on an empty numba cache, and
each compiled function's time split by numba's own timers into LLVM's part and the rest (numba's typing and lowering,
in Python).

Numba records, in each compiled signature's metadata, the time it held its compiler lock (the whole compile, the
helpers it compiled for it included) and the time in LLVM. A module's time is its ``warm_up`` (wall, one core); the
first module also carries numba's first compile in a process (its typing and target contexts).

    python docs/scripts/compile_times.py            # the evaluator's modules (a cold evaluation compiles these)
    python docs/scripts/compile_times.py --all      # the identifier's too (snac-adaptive)

It sets ``NUMBA_CACHE_DIR`` to a new temporary folder before numba is imported, so nothing is loaded from a cache, and
removes it at the end.
"""

from __future__ import annotations

import argparse
import atexit
import importlib
import os
import shutil
import tempfile
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="every kernel module, the identifier's included")
    args = parser.parse_args()
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="compile-times-")
    atexit.register(shutil.rmtree, os.environ["NUMBA_CACHE_DIR"], ignore_errors=True)  # its compiles serve no one else
    from numba.core.registry import CPUDispatcher  # after NUMBA_CACHE_DIR: numba reads it at import

    from snac_gym.kernels import compiled

    modules = compiled.KERNEL_MODULES if args.all else compiled.EVALUATOR_KERNEL_MODULES
    total = 0.0
    print(f"{'module / function':48s} {'wall s':>7s} {'compile s':>9s} {'LLVM s':>7s} {'numba s':>8s}")
    for name in modules:
        module = importlib.import_module(name)
        started = time.perf_counter()
        compiled.warm_up((name,))
        took = time.perf_counter() - started
        total += took
        print(f"{name:48s} {took:7.2f}")
        dispatchers = [getattr(value, "dispatcher", value) for value in vars(module).values()]
        dispatchers += [dispatcher for dispatcher, _ in getattr(module, "lazy_kernels", list)()]
        seen = set()
        for dispatcher in dispatchers:
            if not isinstance(dispatcher, CPUDispatcher) or id(dispatcher) in seen:
                continue
            seen.add(id(dispatcher))
            for signature in dispatcher.signatures:
                timers = dispatcher.get_metadata(signature).get("timers", {})
                whole, llvm = timers.get("compiler_lock", 0.0), timers.get("llvm_lock", 0.0)
                label = f"  {dispatcher.py_func.__module__.rsplit('.', 1)[-1]}.{dispatcher.py_func.__name__}"
                print(f"{label:48s} {'':7s} {whole:9.2f} {llvm:7.2f} {whole - llvm:8.2f}")
    print(f"{'all':48s} {total:7.2f}")


if __name__ == "__main__":
    main()
