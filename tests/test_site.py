"""Every page of the built site opened in headless Chromium (tools/site_check.py): the maths typeset by the site's
own KaTeX, no maths source left as text, every image loaded, no error in the console.

Skipped where Chromium is missing (.ci/run installs Debian's ``chromium``) or the docs extra is not installed.
``python tools/site_check.py SITE --screenshots DIR`` saves a PNG of each page to look at.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site_check():
    spec = importlib.util.spec_from_file_location("site_check", ROOT / "tools" / "site_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def checked(site_check, tmp_path_factory):
    binary = site_check.chromium()
    if binary is None:
        pytest.skip("no Chromium on the PATH (.ci/run installs Debian's chromium)")
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        pytest.skip("the docs extra is not installed: pip install -e '.[docs]'")
    site = tmp_path_factory.mktemp("site") / "site"
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert built.returncode == 0, built.stderr[-4000:]
    results, errors = site_check.check(site, binary)
    return site, results, errors


@pytest.mark.slow(seconds=30)
def test_every_page_renders_with_its_maths_typeset_and_its_images(site_check, checked):
    site, results, _ = checked
    assert len(results) == len(site_check.pages(site)) >= 30
    assert not site_check.problems(results)
    by_path = {"/" + page["url"].split("/", 3)[-1]: page for page in results}
    for page in ("/mpc/", "/evaluation/", "/rl/", "/environments/"):  # the pages with maths: all of it typeset
        assert by_path[page]["maths"] > 0 and by_path[page]["typeset"] == by_path[page]["maths"], page
    assert "/irl/" in by_path and any(page["images"] for page in results)


def test_no_page_logs_a_console_error(checked):
    _, _, errors = checked
    assert not errors, "\n".join(errors)


def test_the_maths_and_fonts_come_from_the_site_not_a_cdn():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "javascripts/katex/katex.min.js" in config and "font: false" in config and "://" not in config
    assert (ROOT / "docs" / "javascripts" / "katex" / "fonts" / "KaTeX_Main-Regular.woff2").is_file()
