"""Optional dependencies: importing one that is not installed gives one line naming the extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType


class MissingExtraError(ImportError, ValueError):
    """An optional dependency is not installed. A ``ValueError`` too, so that every command that turns bad
    input into one line (``snac-gym demo``, ``evaluate``, ``bench``) prints it as such, not as a traceback."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module``, or raise one line: ``"<what> needs the '<extra>' extra: pip install -e ".[<extra>]"``.

    Raises:
        MissingExtraError: If ``module`` (or one of its own dependencies) cannot be imported.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(f"{what} needs the '{extra}' extra: pip install -e \".[{extra}]\"") from exc
