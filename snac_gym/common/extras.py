"""Optional dependencies: importing one that is not installed gives one line naming the extra to install."""

from __future__ import annotations

import functools
import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path
from types import ModuleType

from snac_gym.common._signals import interrupt_behind
from snac_gym.common.errors import MissingExtraError


def install_line(extra: str) -> str:
    """The command that installs ``extra`` where this snac-gym came from: every missing extra is named so.

    From a checkout (the README's editable install, run from its folder): ``pip install -e ".[extra]"``. From a wheel,
    an archive or a repository URL, that source again (pip records it in the install's ``direct_url.json``), as a
    PEP 508 requirement; from a package index, the name on that index.
    """
    source = _install_source(Path(__file__).resolve().parents[2])
    if source is None:
        return f'pip install -e ".[{extra}]"'
    return f'pip install "snac-gym[{extra}]{source}"'


@functools.cache
def _install_source(root: Path) -> str | None:
    """``None`` for a checkout, else what follows ``snac-gym[extra]`` in a requirement: ``" @ <url>"`` or ``""``.

    ``root`` is the folder that holds ``snac_gym/``: a checkout's, with the project's pyproject.toml, or site-packages.
    """
    try:
        if 'name = "snac-gym"' in (root / "pyproject.toml").read_text(encoding="utf-8"):
            return None
    except OSError:
        pass
    # Only for an install, and only when an extra is missing: importlib.metadata costs 20 ms to import.
    import importlib.metadata

    try:
        record = json.loads(importlib.metadata.distribution("snac-gym").read_text("direct_url.json") or "{}")
    except (importlib.metadata.PackageNotFoundError, ValueError):
        return ""
    url = record.get("url") if isinstance(record, dict) else None
    if not isinstance(url, str) or not url:
        return ""  # from an index
    vcs = record.get("vcs_info")
    if isinstance(vcs, dict) and vcs.get("vcs") and vcs.get("commit_id"):
        return f" @ {vcs['vcs']}+{url}@{vcs['commit_id']}"
    return f" @ {url}"


def missing_extra(what: str, extra: str) -> str:
    """The one line that says ``what`` needs ``extra`` and how to install it."""
    return f"{what} needs the '{extra}' extra: {install_line(extra)}"


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module``, or raise one line: ``"<what> needs the '<extra>' extra: pip install -e ".[<extra>]"``.

    Raises:
        MissingExtraError: If ``module`` (or one of its own dependencies) cannot be imported.
        KeyboardInterrupt: If a stop signal came during the import, which an extension turned into an
            ``ImportError``: an interrupted import is not a missing package.
    """
    _name_the_glfw_library()
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        interrupt = interrupt_behind(exc)
        if interrupt is not None:
            raise interrupt from None
        raise MissingExtraError(missing_extra(what, extra)) from exc


def require_installed(module: str, extra: str, what: str) -> None:
    """As :func:`require`, for a module another process imports (ur_rtde, in its client process): found, not imported.

    Raises:
        MissingExtraError: If ``module`` is not installed.
    """
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise MissingExtraError(missing_extra(what, extra))


def _name_the_glfw_library() -> None:
    """Point pyGLFW at the library its wheel bundles, unless ``PYGLFW_LIBRARY`` names one already.

    ``import mujoco`` (and so mink's) imports pyGLFW, which, told no library, starts a Python subprocess
    per candidate file to read its version: 0.07 s quiet and far more on a busy machine, on every import
    in every process, and a stop signal during it leaves that child to print an ``EOFError`` traceback
    after the command has ended. Nothing here draws through GLFW (MuJoCo renders on EGL or OSMesa), and
    the bundled library is the one that search finds where no newer GLFW is installed system-wide.
    """
    if os.environ.get("PYGLFW_LIBRARY") or not sys.platform.startswith("linux") or "glfw" in sys.modules:
        return
    try:
        spec = importlib.util.find_spec("glfw")
    except (ImportError, ValueError):
        return
    if spec is None or not spec.submodule_search_locations:
        return
    variant = os.environ.get("PYGLFW_LIBRARY_VARIANT", "").lower()
    if variant not in ("wayland", "x11"):  # pyGLFW's own default
        variant = "wayland" if os.environ.get("XDG_SESSION_TYPE") == "wayland" else "x11"
    library = os.path.join(next(iter(spec.submodule_search_locations)), variant, "libglfw.so")
    if os.path.isfile(library):
        os.environ["PYGLFW_LIBRARY"] = library


#: MissingExtraError is re-exported: the error of :func:`require`, caught where it is called.
__all__ = ["MissingExtraError", "install_line", "missing_extra", "require", "require_installed"]
