"""The documentation: the site builds in strict mode and renders in headless Chromium, and every ```python block
of README.md and docs/*.md runs.

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
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from snac_gym.common.extras import install_line

ROOT = Path(__file__).resolve().parents[2]
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
        block = {
            "file": path.relative_to(ROOT).as_posix(),
            "line": start + 1,
            "code": "\n".join(lines[start:end]) + "\n",
            "reason": opt_out.group("reason").strip(" :-") if opt_out else None,
        }
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
#: The other extras a block may need, by what it says: the extra, the modules it installs, the words that need it.
NEEDS_EXTRA = [
    ("mujoco", ("mujoco",), re.compile(r"""physics=["']mujoco["']|^\s*(from|import) mujoco\b""", re.MULTILINE)),
    (
        "ik",
        ("pink", "mink", "qpsolvers"),
        re.compile(r"""["'](pink|mink)["']|^\s*(from|import) (pink|mink|qpsolvers)\b""", re.MULTILINE),
    ),
]


def _doc_param(path: Path) -> object:
    """``path``, marked ``rl`` where a block needs torch, and skipped, saying why, where a block needs another extra
    that is not installed (the README's test command installs them all: nothing is skipped there)."""
    code = "\n".join(block["code"] for block in code_blocks(path)[0])
    marks = [pytest.mark.rl] if NEEDS_RL.search(code) else []
    for extra, modules, words in NEEDS_EXTRA:
        missing = [name for name in modules if importlib.util.find_spec(name) is None]
        if words.search(code) and missing:
            reason = f"a block needs the {extra!r} extra (missing: {', '.join(missing)}): {install_line(extra)}"
            marks.append(pytest.mark.skip(reason=reason))
    return pytest.param(path, marks=marks)


@pytest.mark.slow(seconds=1.5)
@pytest.mark.parametrize(
    "path", [_doc_param(path) for path in FILES_WITH_CODE], ids=lambda path: path.relative_to(ROOT).as_posix()
)
def test_python_blocks_run(path: Path, tmp_path: Path):
    blocks, _ = code_blocks(path)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
        "MPLBACKEND": "Agg",
        "OMP_NUM_THREADS": "1",
    }
    result = subprocess.run(
        [sys.executable, "-c", RUNNER],
        input=json.dumps(blocks),
        text=True,
        capture_output=True,
        cwd=tmp_path,
        env=env,
        timeout=300,
    )
    assert result.returncode == 0, f"a python block of {path.name} failed:\n{result.stderr[-4000:]}"


#: The docs build of README.md and CONTRIBUTING.md, run as written there (no ``--quiet``: with it, mkdocs
#: logs no warning, so strict mode has none to abort on and a broken link or anchor passes).
DOCS_BUILD = ["mkdocs", "build", "--strict"]
#: A line mkdocs logs at WARNING level (after its colour codes are removed).
WARNING_LINE = re.compile(r"^WARNING\b.*$", re.MULTILINE)
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _build_site(root: Path, site: Path) -> tuple[int, str, list[str]]:
    """``mkdocs build --strict`` of ``root``'s mkdocs.yml into ``site``: exit code, output, WARNING lines."""
    missing = _missing_docs_packages()
    if missing:
        pytest.skip(
            f"the docs extra is not installed (missing: {', '.join(missing)}); "
            "pip install -e '.[docs]' to build the site"
        )
    result = subprocess.run(
        [sys.executable, "-m", *DOCS_BUILD, "-d", str(site)],
        cwd=root,
        text=True,
        capture_output=True,
        timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    output = ANSI.sub("", result.stdout + result.stderr)
    return result.returncode, output, WARNING_LINE.findall(output)


@pytest.fixture(scope="module")
def built_site(tmp_path_factory, once) -> tuple[int, str, list[str], Path]:
    """The site built once for this module's tests, as README.md says: exit code, output, WARNING lines, folder.
    Once per test session, not once per pytest-xdist worker that runs one of them (``once``, tests/conftest.py)."""

    def build() -> tuple[int, str, list[str], str]:
        site = tmp_path_factory.mktemp("docs") / "site"
        return (*_build_site(ROOT, site), str(site))

    code, output, warnings, site = once("docs-built-site", build)
    return code, output, warnings, Path(site)


@pytest.mark.slow(seconds=30)
def test_the_site_builds_in_strict_mode(built_site):
    for guide in ("README.md", "CONTRIBUTING.md"):  # the command the test runs is the one they give
        assert " ".join(DOCS_BUILD) in (ROOT / guide).read_text(encoding="utf-8"), guide
    code, output, warnings, site = built_site
    assert code == 0 and not warnings, f"mkdocs build --strict failed:\n{output[-6000:]}"
    assert (site / "index.html").is_file()
    assert (site / "api" / "envs" / "index.html").is_file()


#: Emphasis that begins inside a word: Markdown took a formula's asterisks (P*, K*, c*) for italics, and the page shows
#: ``‖P̂ − P(J)‖/‖P‖`` with the stars gone and the middle slanted.
EMPHASIS_INSIDE_A_WORD = re.compile(r"[\w)\]]<em>([^<]{0,40})")


def test_no_formula_loses_its_asterisks_to_italics(built_site):
    code, output, _, site = built_site
    assert code == 0, output[-4000:]
    found = [
        f"{page.relative_to(site)}: …{match.group(0)}"
        for page in sorted(site.rglob("*.html"))
        for match in EMPHASIS_INSIDE_A_WORD.finditer(page.read_text(encoding="utf-8"))
    ]
    assert not found, "write P\\* in Markdown, or the formula in backticks in a docstring:\n" + "\n".join(found)


# The built site opened in headless Chromium (tools/site_check.py): the maths typeset by the site's own KaTeX, no
# maths source left as text, every image loaded, no error in the console. Skipped where Chromium is missing
# (.ci/run installs Debian's ``chromium``). ``python tools/site_check.py SITE --screenshots DIR`` saves a PNG of
# each page to look at.


@pytest.fixture(scope="module")
def site_check():
    spec = importlib.util.spec_from_file_location("site_check", ROOT / "tools" / "site_check.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def checked(site_check, built_site, once):
    binary = site_check.chromium()
    if binary is None:
        pytest.skip("no Chromium on the PATH (.ci/run installs Debian's chromium)")
    code, output, _, site = built_site
    assert code == 0, output[-4000:]
    # Once per test session, as the site it reads (Chromium: ~5 s of two cores)
    results, errors = once("docs-site-check", lambda: site_check.check(site, binary))
    return site, results, errors


def test_every_page_renders_with_its_maths_typeset_and_its_images(site_check, checked):
    site, results, _ = checked
    assert len(results) == len(site_check.pages(site)) >= 30
    assert not site_check.problems(results)
    by_path = {"/" + page["url"].split("/", 3)[-1]: page for page in results}
    for page in ("/mpc/", "/evaluation/", "/rl/", "/environments/"):  # the pages with maths: all of it typeset
        assert by_path[page]["maths"] > 0 and by_path[page]["typeset"] == by_path[page]["maths"], page
    assert "/irl/" in by_path and any(page["images"] for page in results)


def test_the_search_index_is_served_whole_once_then_as_its_first_entry(site_check, tmp_path):
    """The check builds the site's whole search index once, on the first page that asks (each page's search
    worker builds what it gets): the server gives the file itself first, then a valid index of its first entry, and
    tells the browser not to keep either, so that every later page asks it again."""
    import urllib.request

    index = {
        "config": {"lang": ["en"]},
        "docs": [{"location": f"page{i}/", "text": "x", "title": str(i)} for i in range(3)],
    }
    (tmp_path / "search").mkdir()
    (tmp_path / "search" / "search_index.json").write_text(json.dumps(index), encoding="utf-8")
    (tmp_path / "index.html").write_text("<html></html>", encoding="utf-8")
    with site_check.served(tmp_path) as base:
        answers = [urllib.request.urlopen(base + "search/search_index.json", timeout=10) for _ in range(3)]
        bodies = [json.loads(answer.read()) for answer in answers]
        page = urllib.request.urlopen(base, timeout=10).read()
    assert bodies[0] == index
    assert bodies[1] == bodies[2] == {**index, "docs": index["docs"][:1]}
    assert all(answer.headers["Cache-Control"] == "no-store" for answer in answers)
    assert page == b"<html></html>"


def test_no_page_logs_a_console_error(checked):
    _, _, errors = checked
    assert not errors, "\n".join(errors)


def test_the_maths_and_fonts_come_from_the_site_not_a_cdn():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "javascripts/katex/katex.min.js" in config and "font: false" in config and "://" not in config
    assert (ROOT / "docs" / "javascripts" / "katex" / "fonts" / "KaTeX_Main-Regular.woff2").is_file()


def test_a_broken_anchor_fails_the_strict_build(tmp_path: Path):
    """The site's own configuration (its validation settings, plugins and hook) on two pages, one linking to an
    anchor the other has and to one it has not: the build aborts and names the missing anchor only. (Two pages
    rather than a copy of the whole site: the same settings decide, in a tenth of the time.)"""
    copy = tmp_path / "repo"
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = re.search(r"^nav:\n(?:[ \t].*\n|\n)*", config, re.MULTILINE)
    assert nav is not None, "mkdocs.yml has no nav section"
    (copy / "docs").mkdir(parents=True)
    (copy / "mkdocs.yml").write_text(config[: nav.start()] + config[nav.end() :], encoding="utf-8")
    shutil.copytree(ROOT / "docs" / "hooks", copy / "docs" / "hooks", ignore=shutil.ignore_patterns("__pycache__"))
    for entry in ROOT.iterdir():  # what the build reads besides: the package (the hook lays it out), tools/
        if not entry.name.startswith(".") and entry.name not in {"docs", "mkdocs.yml", "build", "site"}:
            (copy / entry.name).symlink_to(entry)
    (copy / "docs" / "index.md").write_text("# Target\n\n## A real heading\n\ntext\n", encoding="utf-8")
    (copy / "docs" / "linking.md").write_text(
        "# Linking\n\n[fine](index.md#a-real-heading) and [broken](index.md#no-such-anchor)\n", encoding="utf-8"
    )
    code, output, warnings = _build_site(copy, tmp_path / "site")
    assert code != 0 and "Aborted with" in output, output[-6000:]
    assert warnings and all("linking.md" in line and "index.md#no-such-anchor" in line for line in warnings), output


def _missing_docs_packages() -> list[str]:
    """The packages of the ``docs`` extra that are not installed."""
    modules = {
        "mkdocs": "mkdocs",
        "mkdocs-material": "material",
        "mkdocstrings": "mkdocstrings",
        "mkdocstrings-python": "mkdocstrings_handlers",
    }
    return [package for package, module in modules.items() if importlib.util.find_spec(module) is None]


def test_no_page_names_a_tracker_issue():
    """What a reader sees says what changed and why, not which tracker issue asked for it (that is the CHANGELOG's
    history and the commits'): no "issue 62", "(issue 59)" or "#61" in the README, the docs or the CHANGELOG."""
    pattern = re.compile(r"\bissues?\s+#?\d+|\(#\d+\)", re.IGNORECASE)
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("**/*.md"))]
    found = [f"{page.relative_to(ROOT)}:{number}: {line.strip()[:80]}" for page in pages
             for number, line in enumerate(page.read_text().splitlines(), 1) if pattern.search(line)]  # fmt: skip
    assert not found, "\n".join(found)
