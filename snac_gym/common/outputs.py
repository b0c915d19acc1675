"""The outputs of the commands (``evaluate``, ``demo``, ``train-ppo``, ``real``): the folder checked in one place,
and every file written whole.

:func:`written_whole` is the one way a file is written: to a temporary name beside it, then renamed, so that a file
under its final name is complete (a full disk, a crash or a stop leaves the old file or none, never a truncated
one); a failure names the file and the space left on its disk.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from snac_gym.common.errors import OutputFolderError, OutputWriteError


def _kind(path: Path) -> str:
    mode = path.stat().st_mode
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a file"


def usable_out_folder(root: Path) -> None:
    """Create the output folder ``root``, or refuse it in one line saying why.

    Raises:
        OutputFolderError: If ``root`` is empty, a file, cannot be created or is not writable.
    """
    root = Path(root)
    if not str(root).strip():
        raise OutputFolderError("the output folder (--out) is empty; name a folder")
    if root.exists() and not root.is_dir():
        raise OutputFolderError(f"the output folder {root} is {_kind(root)}, not a folder; choose another --out")
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"cannot create the output folder {root}: {exc.strerror or exc}") from None
    if not os.access(root, os.W_OK | os.X_OK):
        raise OutputFolderError(f"the output folder {root} is not writable; choose another --out")


@contextlib.contextmanager
def removed_if_left_empty(root: Path | None) -> Iterator[None]:
    """Create the output folder ``root`` as :func:`usable_out_folder` does; if what runs inside fails before anything
    was written in it, remove it again, where this call made it.

    A run refused before its work (a controller that does not answer, a bad option found late) then leaves no empty
    folder behind to be mistaken for a run's. Anything written in it stays, as does a folder that was there before.
    """
    made: list[Path] = []  # the folders this call makes, innermost first
    if root is not None:
        folder = Path(root).absolute()
        while not folder.exists() and folder != folder.parent:
            made.append(folder)
            folder = folder.parent
    try:
        if root is not None:  # a refusal here (a file, not writable) removes what mkdir made on the way too
            usable_out_folder(root)
        yield
    except BaseException:
        for folder in made:
            try:
                folder.rmdir()
            except OSError:  # not empty (or gone): what is there stays, and so do the folders above it
                break
        raise


def _free_space(folder: Path) -> str:
    try:
        free: float = shutil.disk_usage(folder).free
    except OSError:
        return "free space unknown"
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if free < 1000 or unit == "TB":
            return f"{free:.0f} {unit} free" if unit == "B" else f"{free:.1f} {unit} free"
        free /= 1000
    return ""


def write_error(path: str | Path, error: OSError) -> OutputWriteError:
    """The error to raise for a failed write of ``path``: naming it and the free space of its disk."""
    if isinstance(error, OutputWriteError):
        return error
    path = Path(path)
    written = OutputWriteError(f"could not write {path}: {error.strerror or error} ({_free_space(path.parent)})")
    written.errno = error.errno  # the cause's, for callers that test it; the message stays one plain line
    return written


@contextlib.contextmanager
def written_whole(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (with its suffix, so writers that read it pick the format) to write to;
    renamed to ``path`` when the block ends without an error, removed otherwise.

    Raises:
        OutputWriteError: If writing or renaming fails with an ``OSError``: naming ``path`` and the free space.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.{threading.get_ident()}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise write_error(path, exc) from exc
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def write_whole(path: str | Path, write: Callable[[Path], object]) -> Path:
    """``write(temporary)`` then the rename of :func:`written_whole`; returns ``path``."""
    with written_whole(path) as temporary:
        write(temporary)
    return Path(path)


def write_text_whole(path: str | Path, text: str) -> Path:
    """``text`` written whole to ``path`` (:func:`written_whole`)."""
    return write_whole(path, lambda temporary: temporary.write_text(text))


def read_json_object(path: Path) -> dict[str, Any] | str:
    """The JSON object a command wrote to ``path``, or why it cannot be read, in a few words for an error line
    (the exception's, or ``"not a JSON object"``)."""
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        return f"{type(exc).__name__}: {exc}"
    return found if isinstance(found, dict) else "not a JSON object"


__all__ = [
    "OutputFolderError", "OutputWriteError", "read_json_object", "removed_if_left_empty", "usable_out_folder",
    "write_error", "write_text_whole", "write_whole", "written_whole",
]  # fmt: skip
