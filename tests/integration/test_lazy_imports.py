"""Every import made inside a function says why in a short comment (an optional extra, start-up time, ...).

An import with no reason to be in a function belongs with the module's other imports. The comment is on
the import's line, or on the line directly above the block of consecutive imports it belongs to.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The package's folders (baselines/ and evaluation/ install as snac_gym.baselines and snac_gym.evaluation).
FOLDERS = ("snac_gym", "baselines", "evaluation")


def uncommented_function_imports(root: Path, folders: tuple[str, ...] = FOLDERS) -> list[str]:
    """``path:line: import`` for every import inside a function of the ``.py`` files under ``root/folder``
    that has no comment on its lines nor on the line above its block of consecutive imports (blank lines, as
    between import sections, do not end a block)."""
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            source = path.read_text()
            lines = source.splitlines()
            for node in ast.walk(ast.parse(source, filename=str(path))):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                imports = sorted(
                    {
                        (sub.lineno, sub.end_lineno or sub.lineno)
                        for sub in ast.walk(node)
                        if isinstance(sub, (ast.Import, ast.ImportFrom))
                    }  # fmt: skip
                )
                first = 0
                for i, (start, end) in enumerate(imports):
                    previous_end = imports[i - 1][1] if i else -1
                    if not (i and all(not lines[k - 1].strip() for k in range(previous_end + 1, start))):
                        first = start  # a new block of consecutive imports
                    above = lines[first - 2].strip() if first > 1 else ""
                    own = any("#" in lines[k - 1] for k in range(start, end + 1))
                    if not own and not above.startswith("#"):
                        found.append(f"{path.relative_to(root)}:{start}: {lines[start - 1].strip()}")
    return found


def test_every_import_inside_a_function_says_why():
    offenders = uncommented_function_imports(ROOT)
    assert offenders == [], (
        "imports inside functions without a comment saying why (an optional extra, start-up time, ...); "
        "move them to the module's imports if there is no reason:\n" + "\n".join(offenders)
    )


def test_the_check_finds_an_uncommented_import(tmp_path):
    """A planted module: only its uncommented in-function imports are reported."""
    package = tmp_path / "snac_gym"
    package.mkdir()
    (package / "planted.py").write_text(
        "import json\n"
        "\n"
        "\n"
        "def uncommented():\n"
        "    import csv\n"
        "\n"
        "    from pathlib import Path\n"
        "    return csv, Path\n"
        "\n"
        "\n"
        "def commented():\n"
        "    # the rl extra\n"
        "    import torch\n"
        "    import stable_baselines3\n"
        "\n"
        "    import moviepy  # the video extra\n"
        "    return torch, stable_baselines3, moviepy\n"
        "\n"
        "\n"
        "class Holder:\n"
        "    def method(self):\n"
        "        if self:\n"
        "            import ray\n"
        "        return ray\n"
    )
    assert uncommented_function_imports(tmp_path, ("snac_gym",)) == [
        "snac_gym/planted.py:5: import csv",
        "snac_gym/planted.py:7: from pathlib import Path",
        "snac_gym/planted.py:23: import ray",
    ]
