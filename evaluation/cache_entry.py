"""A cache entry that proves what it hands back: one JSON file holding the key it was computed for, its payload
and the SHA-256 of both.

Both of the evaluator's caches (the reference's rows, :mod:`snac_gym.evaluation.reference.cache`, and the matched
knobs, :mod:`snac_gym.evaluation.effort.cache`) store their entries this way. On read, an entry is used only if it
parses, holds the key it is asked for (the whole key: a file copied or renamed under another name is refused) and
its checksum matches its content; the caller then checks the values as it checks fresh ones. Anything else is a
*damaged* entry: :func:`read_entry` raises :class:`DamagedEntry` naming the file and what is wrong, and the caller
computes the value again. A cache never hands back numbers it cannot vouch for.

JSON keeps every float bit for bit (``repr``; NaN and ±inf as JSON's extensions), so the canonical text the
checksum covers is the same after a round trip.

Writes are atomic (a temporary name, then a rename), and a cache that cannot be written says so once
(:class:`CacheWarnings`) and lets the run go on without it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import threading
from pathlib import Path
from typing import Any

from snac_gym.common.errors import DamagedEntry

#: Format of an entry; an entry of another format is damaged (computed again).
ENTRY_FORMAT = 1


def _canonical(key: Any, payload: Any) -> str:
    return json.dumps({"key": key, "payload": payload}, sort_keys=True, separators=(",", ":"), allow_nan=True)


def checksum(key: Any, payload: Any) -> str:
    """SHA-256 of the canonical JSON of ``key`` and ``payload``."""
    return hashlib.sha256(_canonical(key, payload).encode()).hexdigest()


def entry_text(key: Any, payload: Any) -> str:
    """The file's text: the format, the key, the payload and their checksum."""
    # The payload keeps its own order (a row's columns); the checksum's canonical text sorts it.
    return json.dumps({"format": ENTRY_FORMAT, "key": key, "payload": payload, "sha256": checksum(key, payload)},
                      allow_nan=True)  # fmt: skip


def write_entry(path: Path, key: Any, payload: Any) -> None:
    """Write the entry atomically (a reader sees the old file, the new one, or none).

    Raises:
        OSError: If the folder or the file cannot be written (the temporary file is removed).
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    if path.is_dir() and not path.is_symlink():
        path.rmdir()  # an empty folder in the way of a damaged entry goes; a full one raises, and is reported
    try:
        temporary.write_text(entry_text(key, payload))
        os.replace(temporary, path)
    except OSError:
        temporary.unlink(missing_ok=True)
        raise


def read_entry(path: Path, key: Any) -> Any:
    """The payload stored at ``path`` for ``key``, or ``None`` where there is no entry.

    Raises:
        DamagedEntry: If the file is there but unreadable (a folder in the way, not JSON), of another format,
            of another key, or its checksum does not match its content.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (FileNotFoundError, NotADirectoryError):  # no entry (a file in the way of the folder: none can be there)
        return None
    except OSError as exc:
        raise DamagedEntry(path, f"unreadable ({exc.strerror or exc})") from None
    try:
        entry = json.loads(text)
    except ValueError:
        raise DamagedEntry(path, "not JSON") from None
    if not isinstance(entry, dict) or set(entry) != {"format", "key", "payload", "sha256"}:
        raise DamagedEntry(path, "not an entry of this cache (fields missing or extra)")
    if entry["format"] != ENTRY_FORMAT:
        raise DamagedEntry(path, f"entry format {entry['format']!r}, this version reads {ENTRY_FORMAT}")
    if entry["sha256"] != checksum(entry["key"], entry["payload"]):
        raise DamagedEntry(path, "its content does not match its SHA-256 (edited or damaged)")
    if json.loads(json.dumps(key, default=str, allow_nan=True)) != entry["key"]:
        raise DamagedEntry(path, "it holds another key's value")
    return entry["payload"]


class CacheWarnings:
    """The lines a cache writes on stderr: each damaged entry of one read (the first :data:`SHOWN`, then a count),
    and once per folder that cannot be written, naming it and how to run without the cache."""

    #: Damaged entries of one read named one by one; the rest are counted in one more line.
    SHOWN = 3

    def __init__(self, name: str, turn_off: str) -> None:
        self.name, self.turn_off = name, turn_off
        self._lock = threading.Lock()
        self._unwritable: set[str] = set()

    def damaged(self, problems: list[DamagedEntry]) -> None:
        for problem in problems[: self.SHOWN]:
            _say(
                f"warning: {self.name}: ignored the damaged entry {problem.path} ({problem.reason}); computing it again"
            )
        if len(problems) > self.SHOWN:
            _say(f"warning: {self.name}: {len(problems) - self.SHOWN} more damaged entries in "
                 f"{problems[0].path.parent} ignored and computed again")  # fmt: skip

    def unwritable(self, folder: Path, error: OSError) -> None:
        with self._lock:
            if str(folder) in self._unwritable:
                return
            self._unwritable.add(str(folder))
        reason = error.strerror or str(error)
        _say(f"warning: {self.name}: cannot write to {folder} ({reason}); this run goes on without storing its "
             f"entries ({self.turn_off})")  # fmt: skip


def _say(line: str) -> None:
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


__all__ = ["CacheWarnings", "DamagedEntry", "ENTRY_FORMAT", "checksum", "entry_text", "read_entry", "write_entry"]
