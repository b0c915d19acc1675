"""mkdocs hook: the installed package's layout on disk, for mkdocstrings.

``baselines/`` and ``evaluation/`` install as ``snac_gym.baselines`` and ``snac_gym.evaluation`` (setuptools'
package-dir mapping, pyproject.toml), which griffe's static reader does not follow: it looks for them inside
``snac_gym/``. Before the build, this hook lays out ``build/api-tree/snac_gym`` as the install does (links to
every entry of ``snac_gym/`` plus the two mapped folders), and mkdocs.yml points mkdocstrings there.
"""

from __future__ import annotations

import shutil
from pathlib import Path

MAPPED = {"baselines": "baselines", "evaluation": "evaluation"}


def on_config(config, **kwargs):
    root = Path(config.config_file_path).parent
    tree = root / "build" / "api-tree" / "snac_gym"
    shutil.rmtree(tree.parent, ignore_errors=True)
    tree.mkdir(parents=True)
    for entry in (root / "snac_gym").iterdir():
        if entry.name != "__pycache__":
            (tree / entry.name).symlink_to(entry.resolve())
    for name, folder in MAPPED.items():
        (tree / name).symlink_to((root / folder).resolve())
    return config
