"""Open every page of the built site in headless Chromium: maths typeset, images loaded, no console error.

One Chromium process opens a harness page that loads each page of the site in turn in a frame and reads, once it
has loaded: its ``.arithmatex`` elements (the maths pymdownx.arithmatex marks) and the KaTeX output inside them,
KaTeX's error marks, maths source left as text outside code (``\\(``, ``\\[``, ``$$``), and each image that did not
load. Chromium's console log (``--enable-logging=stderr``) gives the pages' errors. ``--screenshots DIR`` also
saves a PNG of each page (one Chromium run a page: slower) for a person to look at.

The site's search index (one file for every page) is served whole once, to the first page that asks, and as an
index of its first entry after that: each page's search worker builds the index it gets, and building the whole one
on every page was two thirds of the check's time (22 of 33 CPU seconds for 37 pages) for what the first page
already checks.

Usage:
    mkdocs build --strict -d site && python tools/site_check.py site [--screenshots runs/screens]
"""

from __future__ import annotations

import argparse
import functools
import html
import json
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

#: Debian's package name is the binary's; other distributions name it otherwise.
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
HARNESS = "_site_check.html"
FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--mute-audio"]
#: A console line that is a page's error (Chromium logs console messages and failed loads at any level).
ERROR_LINE = re.compile(r"CONSOLE.*\"(Uncaught[^\"]*|[^\"]*(Error|error|Failed)[^\"]*)\"|net::ERR_FILE_NOT_FOUND")

SCRIPT = """
const pages = %s;
const results = [];
function inspect(url, doc) {
  const maths = doc.querySelectorAll(".arithmatex");
  let typeset = 0;
  maths.forEach(m => { if (m.querySelector(".katex")) typeset += 1; });
  const text = doc.body.cloneNode(true);
  text.querySelectorAll("pre, code, .katex, script, style").forEach(e => e.remove());
  const raw = (text.textContent.match(/\\\\\\(|\\\\\\[|\\$\\$/g) || []).length;
  const broken = [...doc.images].filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.getAttribute("src"));
  return {url, title: doc.title, maths: maths.length, typeset, errors: doc.querySelectorAll(".katex-error").length,
          raw, broken, images: doc.images.length};
}
function check(url) {
  return new Promise(resolve => {
    const frame = document.createElement("iframe");
    frame.style.width = "1200px"; frame.style.height = "900px";
    frame.onload = () => setTimeout(() => {
      try { resolve(inspect(url, frame.contentDocument)); } catch (e) { resolve({url, failed: String(e)}); }
      frame.remove();
    }, 20);
    frame.src = url;
    document.body.appendChild(frame);
  });
}
(async () => {
  for (const url of pages) results.push(await check(url));
  const out = document.createElement("pre");
  out.id = "result";
  out.textContent = JSON.stringify(results);
  document.body.appendChild(out);
})();
"""


def chromium() -> str | None:
    """The Chromium binary on the PATH, or ``None``."""
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


def pages(site: Path) -> list[Path]:
    """Every page of the built site (its ``index.html`` files; the 404 page aside)."""
    return sorted(path for path in site.rglob("index.html") if "__" not in str(path.relative_to(site)))


@contextmanager
def served(site: Path) -> Iterator[str]:
    """The site served over HTTP on the loopback address, as a reader's browser gets it (file:// URLs block the
    search index's worker); yields the base URL."""
    handler = functools.partial(_QuietHandler, directory=str(site), index=_SearchIndex(site))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


class _SearchIndex:
    """The site's search index: whole for the first request, its first entry only after that (module docs)."""

    PATH = "/search/search_index.json"

    def __init__(self, site: Path) -> None:
        self.file = site / self.PATH.lstrip("/")
        self.lock = threading.Lock()
        self.served = False
        self.trimmed: bytes | None = None

    def next_body(self) -> bytes | None:
        """What the next request gets (None where the site has no index)."""
        if not self.file.is_file():
            return None
        with self.lock:
            if not self.served:
                self.served = True
                return self.file.read_bytes()
            if self.trimmed is None:  # made once: the whole index is a megabyte to parse
                index = json.loads(self.file.read_text(encoding="utf-8"))
                index["docs"] = index.get("docs", [])[:1]
                self.trimmed = json.dumps(index).encode()
            return self.trimmed


class _QuietHandler(SimpleHTTPRequestHandler):
    def __init__(self, *args: Any, index: _SearchIndex, **kwargs: Any) -> None:
        self.index = index
        super().__init__(*args, **kwargs)

    def do_GET(self) -> None:  # noqa: N802  (the base class's name)
        body = self.index.next_body() if self.path.split("?")[0] == _SearchIndex.PATH else None
        if body is None:
            super().do_GET()
            return
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")  # each page asks the server, not the browser's cache
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002  (the base class's name)
        pass


def check(site: Path, binary: str, timeout: float = 120) -> tuple[list[dict], list[str]]:
    """Each page's findings (see the module docs) and the console lines that are errors.

    Raises:
        RuntimeError: If Chromium printed no result (it crashed, or ran out of its time budget).
    """
    site = site.resolve()
    harness = site / HARNESS
    with served(site) as base, tempfile.TemporaryDirectory(prefix="snac-gym-chromium-") as profile:
        folders = [path.parent.relative_to(site).as_posix() for path in pages(site)]
        urls = [base if folder == "." else f"{base}{folder}/" for folder in folders]
        harness.write_text(f"<!doctype html><html><body><script>{SCRIPT % json.dumps(urls)}</script></body></html>")
        try:
            done = subprocess.run(
                [
                    binary,
                    *FLAGS,
                    f"--user-data-dir={profile}",
                    "--enable-logging=stderr",
                    "--v=0",
                    "--virtual-time-budget=60000",
                    "--dump-dom",
                    base + HARNESS,
                ],
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        finally:
            harness.unlink()
    match = re.search(r'<pre id="result">(.*?)</pre>', done.stdout, re.S)
    if match is None:
        raise RuntimeError(f"Chromium gave no result (exit {done.returncode}):\n{done.stderr[-3000:]}")
    errors = [line for line in done.stderr.splitlines() if ERROR_LINE.search(line)]
    return json.loads(html.unescape(match[1])), errors


def screenshots(site: Path, binary: str, folder: Path, width: int = 1200, height: int = 2000) -> list[Path]:
    """A PNG of the top of each page (the page's URL without an anchor: with one, pages rendered blank)."""
    folder.mkdir(parents=True, exist_ok=True)
    shots = []
    for page in pages(site.resolve()):
        name = page.parent.relative_to(site.resolve()).as_posix().replace("/", "-") or "index"
        target = folder / f"{name}.png"
        with tempfile.TemporaryDirectory(prefix="snac-gym-chromium-") as profile:
            subprocess.run(
                [
                    binary,
                    *FLAGS,
                    f"--user-data-dir={profile}",
                    "--run-all-compositor-stages-before-draw",
                    "--virtual-time-budget=10000",
                    f"--window-size={width},{height}",
                    f"--screenshot={target}",
                    page.as_uri(),
                ],
                capture_output=True,
                timeout=120,
                check=True,
            )
        shots.append(target)
    return shots


def problems(results: list[dict]) -> list[str]:
    """What is wrong, page by page: maths not typeset or in error, maths source left as text, broken images."""
    found = []
    for page in results:
        where = "/" + page["url"].split("/", 3)[-1]  # the page's path on the site
        if "failed" in page:
            found.append(f"{where}: could not be read ({page['failed']})")
            continue
        if page["typeset"] != page["maths"] or page["errors"]:
            found.append(f"{where}: {page['typeset']} of {page['maths']} maths typeset, {page['errors']} in error")
        if page["raw"]:
            found.append(f"{where}: {page['raw']} maths delimiters left as text")
        if page["broken"]:
            found.append(f"{where}: images not loaded: {page['broken']}")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("site", type=Path, help="the built site (mkdocs build -d SITE)")
    parser.add_argument("--screenshots", type=Path, help="also save a PNG of each page here")
    args = parser.parse_args(argv)
    binary = chromium()
    if binary is None:
        print("no Chromium on the PATH (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    results, errors = check(args.site, binary)
    found = problems(results) + [f"console: {line}" for line in errors]
    maths = sum(page.get("maths", 0) for page in results)
    print(f"{len(results)} pages, {maths} maths elements, {sum(p.get('images', 0) for p in results)} images")
    if args.screenshots:
        print(f"{len(screenshots(args.site, binary, args.screenshots))} screenshots in {args.screenshots}")
    for line in found:
        print(line, file=sys.stderr)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
