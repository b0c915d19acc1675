"""The top-level import names of snac-gym 0.1.0 that 0.2.0 moved into ``snac_gym``: an import of one names its
new home instead of a bare "No module named ...". Kept for the 0.2 releases; removed in 0.3.0."""

from __future__ import annotations

import importlib.abc
import sys

#: Old top-level import name → its import name since 0.2.0.
RENAMED = {"baselines": "snac_gym.baselines", "evaluation": "snac_gym.evaluation"}


class RenamedFinder(importlib.abc.MetaPathFinder):
    """Last on ``sys.meta_path``: reached only when no installed package has the old name (OpenAI Baselines,
    if installed, is still found as ``baselines``)."""

    def find_spec(self, fullname, path=None, target=None):  # noqa: ANN001 - the importlib protocol
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
