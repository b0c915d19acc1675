"""mkdocs hook: the installed package's layout on disk, for mkdocstrings.

``baselines/`` and ``evaluation/`` install as ``snac_gym.baselines`` and ``snac_gym.evaluation`` (setuptools'
package-dir mapping, pyproject.toml), which griffe's static reader does not follow: it looks for them inside
``snac_gym/``. Before the build, this lays out ``build/api-tree/snac_gym`` as the install does (the layout of
``tools/lint_imports.py``), and mkdocs.yml points mkdocstrings there.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path


def on_config(config, **kwargs):
    root = Path(config.config_file_path).parent
    spec = importlib.util.spec_from_file_location("lint_imports", root / "tools" / "lint_imports.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    tool.lay_out(root, root / "build" / "api-tree")
    return config
