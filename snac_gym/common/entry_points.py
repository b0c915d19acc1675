"""An entry-point group read once per process: what the task and robot registries load from other packages."""

from __future__ import annotations

import importlib.metadata
from collections.abc import Iterator
from typing import Any


class EntryPointGroup:
    """The entry points of ``group`` not loaded yet, each loaded once.

    The installed packages are scanned on the first call of the process (a scan costs ~5 ms; ``rescan=True``
    scans again, after installing one at run time). An entry point counts as loaded, and the scan as done,
    only once the caller has taken it without raising: a broken one fails every lookup alike.
    """

    def __init__(self, group: str) -> None:
        self.group = group
        self._loaded: set[str] = set()
        self._scanned = False

    def new(self, rescan: bool = False) -> Iterator[tuple[importlib.metadata.EntryPoint, Any]]:
        """``(entry point, its loaded object)`` for each not taken yet."""
        if self._scanned and not rescan:
            return
        for entry in importlib.metadata.entry_points(group=self.group):
            if entry.value not in self._loaded:
                yield entry, entry.load()
                self._loaded.add(entry.value)
        self._scanned = True

    def name(self, entry: importlib.metadata.EntryPoint) -> str:
        """How an error names ``entry``: ``entry point NAME = 'module:attr' (group)``."""
        return f"entry point {entry.name} = {entry.value!r} ({self.group})"
