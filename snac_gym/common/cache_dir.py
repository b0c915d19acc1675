"""Where the project keeps what it computes once and reads back: the reference's rows, the matched knobs, the visual
meshes PyBullet loads (each in a folder of its own under :func:`cache_root`)."""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the caches' parent folder.
CACHE_ENV = "SNAC_GYM_CACHE_DIR"


def cache_root() -> Path:
    """The parent of the project's caches: ``$SNAC_GYM_CACHE_DIR``, else ``$XDG_CACHE_HOME/snac-gym`` or
    ``~/.cache/snac-gym``."""
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "snac-gym"


def switched_on(variable: str) -> bool:
    """Whether the environment variable ``variable`` leaves a cache on: it does unless set to ``0``, ``off``, ``false``
    or ``no`` (any case, spaces around ignored)."""
    return os.environ.get(variable, "1").strip().lower() not in ("0", "off", "false", "no")


__all__ = ["CACHE_ENV", "cache_root", "switched_on"]
