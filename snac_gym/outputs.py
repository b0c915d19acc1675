"""The output folders of the commands (``evaluate``, ``demo``, ``train-ppo``, ``real``): one check, one message."""

from __future__ import annotations

import os
import stat
from pathlib import Path


class OutputFolderError(ValueError):
    """An ``--out`` that cannot be used: empty, a file, not creatable or not writable."""


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
