"""Freed memory kept for the next large array in an evaluator's worker, rather than given back and faulted in again.

Each rollout allocates its logs afresh: ``(B, K, m)`` arrays of tens of MB, and a transposed copy
of each. glibc's malloc serves blocks above its mmap threshold (at most 32 MB by default) with
fresh pages from the system and returns them on ``free``, so every such array was faulted in page by
page again: in the README's main command that cost 8–10 s of system time and made the copies 2.5 times
slower than into memory already mapped. Raising the threshold keeps those blocks in the heap, where
the next rollout reuses them (``docs/benchmarks-log.md``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: glibc's mallopt parameters.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: Blocks up to this size come from the heap, and are reused once freed.
MMAP_THRESHOLD = 256 << 20
#: Free memory at the top of the heap up to this size is kept rather than given back.
TRIM_THRESHOLD = 512 << 20


def keep_freed_memory() -> bool:
    """Set this process's malloc to keep and reuse freed large blocks; ``False`` where it is not glibc's."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):  # no libc found, or one without mallopt (musl)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
