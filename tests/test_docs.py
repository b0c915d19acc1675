"""The documentation: the site builds in strict mode, and every ```python block of README.md and
docs/*.md runs.

A block opts out with an HTML comment on the line before its fence, giving the reason:
``<!-- no-test: needs the video extra (moviepy) -->``. The blocks of one file run in order in one
namespace (a later block may use an earlier one's ``env``), in a fresh interpreter per file, so a
task or policy a page registers never reaches another page or test.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```python\s*$")
OPT_OUT = re.compile(r"^<!--\s*no-test\b(?P<reason>.*?)-->\s*$")

#: Runs the blocks given as JSON on stdin, each with its file name and line for tracebacks.
RUNNER = """
import json, sys
ns = {"__name__": "__main__"}
for block in json.load(sys.stdin):
    exec(compile(block["code"], f"{block['file']}:{block['line']}", "exec"), ns)
"""


def code_blocks(path: Path) -> tuple[list[dict], list[dict]]:
    """The ```python blocks of ``path``: (to run, opted out), each ``{file, line, code, reason}``."""
    lines = path.read_text(encoding="utf-8").splitlines()
    run, skipped, i = [], [], 0
    while i < len(lines):
        if not FENCE.match(lines[i]):
            i += 1
            continue
        start = i + 1
        end = next(j for j in range(start, len(lines)) if lines[j].startswith("```"))
        previous = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        opt_out = OPT_OUT.match(previous.strip())
        block = {"file": path.relative_to(ROOT).as_posix(), "line": start + 1,
                 "code": "\n".join(lines[start:end]) + "\n",
                 "reason": opt_out.group("reason").strip(" :-") if opt_out else None}
        (skipped if opt_out else run).append(block)
        i = end + 1
    return run, skipped


FILES_WITH_CODE = [path for path in DOC_FILES if code_blocks(path)[0]]


def test_the_documentation_has_code_to_run_and_few_opt_outs():
    assert ROOT / "README.md" in FILES_WITH_CODE
    skipped = [block for path in DOC_FILES for block in code_blocks(path)[1]]
    for block in skipped:
        assert block["reason"], f"{block['file']}:{block['line']}: a no-test comment must say why"
    assert len(skipped) <= 5, [f"{b['file']}:{b['line']}" for b in skipped]


#: A block that imports stable-baselines3 or torch needs the rl extra.
NEEDS_RL = re.compile(r"^\s*(from|import) (stable_baselines3|torch)\b", re.MULTILINE)


def _doc_param(path: Path) -> object:
    needs_rl = any(NEEDS_RL.search(block["code"]) for block in code_blocks(path)[0])
    return pytest.param(path, marks=pytest.mark.rl) if needs_rl else path


@pytest.mark.slow(seconds=1.5)
@pytest.mark.parametrize("path", [_doc_param(path) for path in FILES_WITH_CODE],
                         ids=lambda path: path.relative_to(ROOT).as_posix())
def test_python_blocks_run(path: Path, tmp_path: Path):
    blocks, _ = code_blocks(path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           "MPLBACKEND": "Agg", "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, "-c", RUNNER], input=json.dumps(blocks), text=True, capture_output=True,
        cwd=tmp_path, env=env, timeout=300,
    )
    assert result.returncode == 0, f"a python block of {path.name} failed:\n{result.stderr[-4000:]}"


@pytest.mark.slow(seconds=4)
def test_the_site_builds_in_strict_mode(tmp_path: Path):
    missing = _missing_docs_packages()
    if missing:
        pytest.skip(f"the docs extra is not installed (missing: {', '.join(missing)}); "
                    "pip install -e '.[docs]' to build the site")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(tmp_path / "site")],
        cwd=ROOT, text=True, capture_output=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout[-3000:]}{result.stderr[-4000:]}"
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "api" / "envs" / "index.html").is_file()


def _missing_docs_packages() -> list[str]:
    """The packages of the ``docs`` extra that are not installed."""
    modules = {"mkdocs": "mkdocs", "mkdocs-material": "material", "mkdocstrings": "mkdocstrings",
               "mkdocstrings-python": "mkdocstrings_handlers"}
    return [package for package, module in modules.items() if importlib.util.find_spec(module) is None]
