"""mkdocs hook: the installed package's layout on disk, for mkdocstrings.

``baselines/`` and ``evaluation/`` install as ``snac_gym.baselines`` and ``snac_gym.evaluation`` (setuptools'
package-dir mapping, pyproject.toml), which griffe's static reader does not follow: it looks for them inside
``snac_gym/``. This lays out ``build/api-tree/snac_gym`` as the install does (the layout of
``tools/lint_imports.py``), and mkdocs.yml points mkdocstrings there. It runs when mkdocs loads the hook, while
reading mkdocs.yml: mkdocstrings keeps only the search paths that exist by its own ``on_config``, which runs
before any hook's.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _lay_out() -> None:
    spec = importlib.util.spec_from_file_location("lint_imports", ROOT / "tools" / "lint_imports.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    tool.lay_out(ROOT, ROOT / "build" / "api-tree")


_lay_out()
