"""Import names that moved: an import of an old one finds its new home.

* The top-level names of snac-gym 0.1.0 that 0.2.0 moved into ``snac_gym`` (``evaluation``, ``baselines``): the
  import fails naming the new one (OpenAI Baselines, if installed, must still be found as ``baselines``).
* The modules of the package root that moved into ``snac_gym.model``, ``snac_gym.control`` and ``snac_gym.common``
  (``snac_gym.kinematics`` is ``snac_gym.model.kinematics``): the old name is the same module object, with a
  ``DeprecationWarning``.

Kept for the 0.2 releases; removed in 0.3.0."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType

#: Old top-level import name → its import name since 0.2.0.
RENAMED = {"baselines": "snac_gym.baselines", "evaluation": "snac_gym.evaluation"}
#: A root module's old name → its module now.
MOVED = {
    f"snac_gym.{name}": f"snac_gym.{package}.{name}"
    for package, names in {
        "model": ("kinematics", "robots", "ur_models", "joint_limits", "joint_goal", "model_error"),
        "control": ("cost", "trajopt", "optimality", "irl"),
        "common": ("_quiet", "_signals", "errors", "extras", "outputs", "progress", "validation", "entry_points"),
    }.items()
    for name in names
}


class _Alias(importlib.abc.Loader):
    """Loads an old name as the module it now is (one object: its classes are the same classes)."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: ModuleSpec) -> ModuleType:
        return importlib.import_module(self.target)

    def exec_module(self, module: ModuleType) -> None:
        return None


class RenamedFinder(importlib.abc.MetaPathFinder):
    """Last on ``sys.meta_path``: reached only when no installed package has the old name (OpenAI Baselines,
    if installed, is still found as ``baselines``)."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> ModuleSpec | None:
        if fullname in MOVED:
            warnings.warn(
                f"{fullname} is {MOVED[fullname]} since snac-gym 0.2.0; the old name goes in 0.3.0",
                DeprecationWarning,
                stacklevel=2,
            )
            return importlib.util.spec_from_loader(fullname, _Alias(MOVED[fullname]))
        top = fullname.partition(".")[0]
        if top in RENAMED:
            new = RENAMED[top] + fullname[len(top) :]
            raise ModuleNotFoundError(
                f"No module named {fullname!r}: snac-gym's {top} package is imported as {RENAMED[top]} since "
                f"0.2.0 (write `import {new}` or `from {new} import ...`)",
                name=fullname,
            )
        return None


def install() -> None:
    """Append the finder to ``sys.meta_path`` once."""
    if not any(isinstance(finder, RenamedFinder) for finder in sys.meta_path):
        sys.meta_path.append(RenamedFinder())
