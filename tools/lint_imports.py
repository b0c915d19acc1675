"""The architecture check of the README's test command: the layers and independence contracts of
pyproject.toml's ``[tool.importlinter]`` (import-linter), and no import cycle between any two modules.

``baselines/`` and ``evaluation/`` install as ``snac_gym.baselines`` and ``snac_gym.evaluation`` (setuptools'
package-dir, pyproject.toml). import-linter and grimp read the package from the file system, so this lays
out ``snac_gym`` as the install does (links in a temporary folder) and analyses that. The cycle check
counts every import, those inside functions and under ``TYPE_CHECKING`` included.

    python tools/lint_imports.py              # the repository's package
    python tools/lint_imports.py --tree DIR   # a tree laid out already
                                              # (tests/integration/test_layers.py plants violations)
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Folders of the repository that install inside snac_gym (pyproject.toml's package-dir).
MAPPED = {"baselines": "baselines", "evaluation": "evaluation"}


def lay_out(repo: Path, dest: Path) -> Path:
    """``dest/snac_gym`` as installed: a link to each entry of ``repo/snac_gym`` and to the mapped folders."""
    tree = dest / "snac_gym"
    shutil.rmtree(dest, ignore_errors=True)
    tree.mkdir(parents=True)
    for entry in (repo / "snac_gym").iterdir():
        if entry.name != "__pycache__":
            (tree / entry.name).symlink_to(entry.resolve())
    for name, folder in MAPPED.items():
        (tree / name).symlink_to((repo / folder).resolve())
    return dest


def import_cycles(tree: Path) -> list[list[str]]:
    """Every import cycle of ``tree/snac_gym``, once each: the chain from a module back to itself."""
    import grimp

    sys.path.insert(0, str(tree))
    graph = grimp.build_graph("snac_gym", include_external_packages=False, cache_dir=None)
    cycles: dict[frozenset[str], list[str]] = {}
    for importer in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            back = graph.find_shortest_chain(importer=imported, imported=importer)
            if back is not None:
                cycles.setdefault(frozenset(back), [importer, *back])
    return list(cycles.values())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, help="analyse this laid-out tree instead of the repository's package")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="snac-gym-layers-") as scratch:  # private: two checks may run at once
        tree = args.tree.resolve() if args.tree else lay_out(ROOT, Path(scratch) / "tree")
        from importlinter.cli import lint_imports

        # import-linter puts the working directory first on sys.path: run it from the tree so that it reads
        # the laid-out package, not the repository's snac_gym/ folder.
        os.chdir(tree)
        status = lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
        cycles = import_cycles(tree)
        os.chdir(ROOT)
    for cycle in cycles:
        print("import cycle: " + " -> ".join(cycle))
    print(f"import cycles: {len(cycles)}")
    return 1 if status or cycles else 0


if __name__ == "__main__":
    sys.exit(main())
