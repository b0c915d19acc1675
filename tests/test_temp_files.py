"""The suite leaves nothing in the machine's temporary folder: a test writes under its ``tmp_path`` (pytest keeps the
last few runs' and removes the older), never where nobody removes it."""

import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent
#: Calls that make a file or folder no one removes unless the caller does: ``tempfile.mkdtemp``/``mkstemp`` and a
#: ``NamedTemporaryFile(delete=False)``. Matched in the text, so that the scripts a test runs in a subprocess (a string)
#: are read too.
LEFT_BEHIND = re.compile(r"\bmkdtemp\(|\bmkstemp\(|\bdelete\s*=\s*False\b")
#: tests/conftest.py makes the suite's cache folder so, and removes it as its process ends (``atexit``).
REMOVED_BY_ITS_MAKER = {TESTS / "conftest.py"}


def offenders(root: Path) -> list[str]:
    """``path:line: text`` of each call of :data:`LEFT_BEHIND` in the Python files under ``root``."""
    found = []
    for path in sorted(root.rglob("*.py")):
        if path in REMOVED_BY_ITS_MAKER or path == Path(__file__).resolve():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if LEFT_BEHIND.search(line):
                found.append(f"{path.relative_to(root.parent)}:{number}: {line.strip()}")
    return found


def test_no_test_writes_temporary_files_that_nobody_removes():
    assert offenders(TESTS) == [], "write under the test's tmp_path instead:\n" + "\n".join(offenders(TESTS))


def test_the_check_finds_each_kind_of_call(tmp_path):
    """A check that finds nothing must be able to find something: each pattern, in code and in a script's string."""
    (tmp_path / "tests").mkdir()
    planted = tmp_path / "tests" / "test_planted.py"
    planted.write_text(
        "import tempfile\n"
        "tempfile.mkdtemp()\n"
        "tempfile.mkstemp(suffix='.urdf')\n"
        "tempfile.NamedTemporaryFile('w', delete=False)\n"
        "script = 'from pathlib import Path; import tempfile; Path(tempfile.mkdtemp())'\n"
        "with tempfile.TemporaryDirectory() as folder: pass\n"  # removed on leaving the block: not an offender
    )
    assert [entry.split(":")[1] for entry in offenders(tmp_path / "tests")] == ["2", "3", "4", "5"]
