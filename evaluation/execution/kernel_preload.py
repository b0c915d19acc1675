"""Imported by the evaluator's fork server (``multiprocessing``'s preload,
:data:`snac_gym.evaluation.execution.worker_setup.PRELOAD`).

Besides the modules the workers run, it loads every compiled kernel from numba's cache, once, in
the server: each worker forked from it then starts with them loaded, instead of loading them
itself (a third of a second of CPU a worker, for every executor a process opens). Only where the
cache is up to date: a kernel still to compile is compiled by the workers, which share that work
(:func:`snac_gym.kernels.compiled.warm_up_shared`).
"""

from __future__ import annotations

import gc

import snac_gym.evaluation.execution.jobs  # noqa: F401  (what the workers run)
import snac_gym.evaluation.reference.optimum  # noqa: F401

from snac_gym.kernels.compiled import load_if_cached

try:
    load_if_cached()
except Exception:  # noqa: BLE001 - the server must start; each worker then loads, and reports, it itself
    pass
# Everything loaded so far lives as long as the server and its workers: frozen, the workers' garbage collector skips
# it (and so leaves the pages they share with the server uncopied), as the console script's after its imports.
gc.freeze()
