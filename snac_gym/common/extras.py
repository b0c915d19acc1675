"""Optional dependencies: importing one that is not installed gives one line naming the extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType

from snac_gym.common._signals import interrupt_behind
from snac_gym.common.errors import MissingExtraError


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module``, or raise one line: ``"<what> needs the '<extra>' extra: pip install -e ".[<extra>]"``.

    Raises:
        MissingExtraError: If ``module`` (or one of its own dependencies) cannot be imported.
        KeyboardInterrupt: If a stop signal came during the import, which an extension turned into an
            ``ImportError``: an interrupted import is not a missing package.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        interrupt = interrupt_behind(exc)
        if interrupt is not None:
            raise interrupt from None
        raise MissingExtraError(f"{what} needs the '{extra}' extra: pip install -e \".[{extra}]\"") from exc


#: MissingExtraError is re-exported: the error of :func:`require`, caught where it is called.
__all__ = ["MissingExtraError", "require"]
