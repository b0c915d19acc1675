"""Every file of the repository the pages and the code point a reader to exists, every ``path::test`` names a
test that is there, and every ``snac_gym.…`` name the pages give is one the package has.

mkdocs' strict build checks the pages' links; a path written as code (``snac_gym/rollout.py``, a script, a test) is
checked by nothing, and the layout moves (``rollout.py`` became ``rollout/``): a reader sent to a file that is gone,
or to a test that no longer exists as evidence, is misled. Left out: the CHANGELOG and the measurement log (records of
their day, naming the files of their day), a placeholder (``configs/TASK.json``), and a file at an old commit
(``git show d0c7f43:snac_gym/...``).
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from snac_gym import policies
from snac_gym.common._renamed import MOVED
from snac_gym.model import robots
from snac_gym.tasks import registry as tasks_registry

ROOT = Path(__file__).resolve().parents[2]
#: The repository's folders a pointer starts from.
TOP = ("snac_gym", "tests", "docs", "tools", "evaluation", "baselines", "examples", ".ci")
POINTER = re.compile(
    rf"(?<![\w./:-])((?:{'|'.join(re.escape(t) for t in TOP)})/[\w./-]*\w\.(?:py|md|json|yml|toml|csv|npz|sh|urdf))"
    r"(?:::(\w+))?"
)
PLACEHOLDER = re.compile(r"(^|/)[A-Z][A-Z_]*(\.|/|$)")
#: Records of their day: they name the files of that day.
RECORDS = {"CHANGELOG.md", "docs/benchmarks-log.md"}


def pointers(text: str) -> list[tuple[str, str]]:
    """``(path, test name or "")`` of each repository file ``text`` names, placeholders left out."""
    return [(path, test) for path, test in POINTER.findall(text) if not PLACEHOLDER.search(path)]


def missing(path: str, test: str) -> str | None:
    """What is wrong with the pointer (``None``: the file, and the test if named, exist)."""
    target = ROOT / path
    if not target.exists():
        return f"{path} does not exist"
    if test and not re.search(rf"^(async )?def {re.escape(test)}\(", target.read_text(), re.M):
        return f"{path} has no test {test}"
    return None


def _sources() -> list[Path]:
    pages = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
    code = [p for folder in ("snac_gym", "evaluation", "baselines", "tools", "docs/scripts", "examples")
            for p in sorted((ROOT / folder).rglob("*.py"))]  # fmt: skip
    return [p for p in pages + code if p.relative_to(ROOT).as_posix() not in RECORDS]


def test_every_file_and_test_the_pages_and_the_code_point_to_exists():
    found = [(p.relative_to(ROOT).as_posix(), path, test) for p in _sources() for path, test in pointers(p.read_text())]
    assert len(found) > 400 and sum(1 for *_, test in found if test) > 20  # the search finds them
    wrong = [f"{where}: {why}" for where, path, test in found if (why := missing(path, test)) is not None]
    assert wrong == []


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("See `snac_gym/rollout.py` for details.", "snac_gym/rollout.py does not exist"),
        ("(`tests/evaluation/test_runner.py::test_no_such_thing`)", "has no test test_no_such_thing"),
        ("(`tests/evaluation/test_runner.py::test_results_have_one_row_per_task_controller_and_sample`)", None),
        ("from `snac_gym/ppo/configs/TASK.json`", "no pointer"),
        ("`git show d0c7f43:snac_gym/ppo/models/workspace/reach.npz`", "no pointer"),
        ("docs/benchmarks-log.md#the-test-suite", None),
    ],
)
def test_a_pointer_to_nothing_is_named(text, why):
    found = pointers(text)
    if why == "no pointer":
        assert found == []
        return
    (pointer,) = found
    result = missing(*pointer)
    assert (result is None) if why is None else (why in result), result


#: The names of the entry-point groups other packages add to, which a page gives as they are published.
ENTRY_POINT_GROUPS = {robots.ENTRY_POINT_GROUP, tasks_registry.ENTRY_POINT_GROUP, policies.ENTRY_POINT_GROUP}
#: A dotted name of the package in a page: ``snac_gym.apps.studies.random_episode_study``.
NAME = re.compile(r"(?<![\w/.])(snac_gym(?:\.\w+)+)")


def unresolved(name: str) -> str | None:
    """Why ``name`` is not a module of the package or an attribute of one (``None``: it is, or the module needs an
    extra that is not installed here, as on the Python 3.13 variant)."""
    if name in ENTRY_POINT_GROUPS:
        return None
    parts = name.split(".")
    for split in range(1, len(parts) + 1):  # a page must give the current name, not the one kept for 0.2
        if (old := ".".join(parts[:split])) in MOVED:
            return f"{old} is {MOVED[old]} since snac-gym 0.2.0"
    for split in range(len(parts), 0, -1):
        module_name = ".".join(parts[:split])
        try:
            found = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and not exc.name.startswith("snac_gym"):
                return None  # a third-party module: an extra not installed here
            continue
        except ImportError:
            return None  # a missing extra, said as snac_gym.common.extras does
        for attribute in parts[split:]:
            if not hasattr(found, attribute):
                return f"{module_name} has no {'.'.join(parts[split:])}"
            found = getattr(found, attribute)
        return None
    return f"no module {name}"


def test_every_name_of_the_package_the_pages_give_is_there():
    pages = [p for p in _sources() if p.suffix == ".md"]
    found = sorted(
        {(p.relative_to(ROOT).as_posix(), n.rstrip(".")) for p in pages for n in NAME.findall(p.read_text())}
    )
    assert len(found) > 60
    wrong = [f"{where}: {why}" for where, name in found if (why := unresolved(name)) is not None]
    assert wrong == []


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("snac_gym.apps.studies.random_episode_study", None),
        ("snac_gym.apps.demo.random_episode_study", "snac_gym.apps.demo has no random_episode_study"),
        ("snac_gym.evaluation.reference.branches", None),
        ("snac_gym.nothing_here", "snac_gym has no nothing_here"),
        ("snac_gym.robots", None),  # the entry-point group
        ("snac_gym.robots.register_robot", "snac_gym.robots is snac_gym.model.robots since snac-gym 0.2.0"),
    ],
)
def test_a_name_the_package_does_not_have_is_named(name, why):
    found = unresolved(name)
    assert (found is None) if why is None else (found is not None and found.startswith(why)), found


def imported_names(code: str) -> list[str]:
    """The package's names ``code`` imports: ``snac_gym.apps.studies.random_episode_study`` for ``from
    snac_gym.apps.studies import random_episode_study``."""
    names = []
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "snac_gym":
            names += [f"{node.module}.{alias.name}" for alias in node.names if alias.name != "*"]
        elif isinstance(node, ast.Import):
            names += [alias.name for alias in node.names if alias.name.split(".")[0] == "snac_gym"]
    return names


def test_every_import_of_the_scripts_and_the_pages_shell_blocks_resolves():
    """The docs' scripts, tools and examples (most too long to run here) and the pages' ``python - <<'PY'`` blocks
    (which tests/integration/test_docs.py does not run): the names they import are the package's today."""
    scripts = [p for folder in ("docs/scripts", "tools", "examples") for p in sorted((ROOT / folder).glob("*.py"))]
    found = [(p.relative_to(ROOT).as_posix(), n) for p in scripts for n in imported_names(p.read_text())]
    heredoc = re.compile(r"python3? - <<'?(\w+)'?\n(.*?)\n\1\n", re.S)
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for _, code in heredoc.findall(page.read_text()):
            found += [(page.relative_to(ROOT).as_posix(), n) for n in imported_names(code)]
    assert len(found) > 250 and any(where.endswith(".md") for where, _ in found)
    wrong = [f"{where}: {why}" for where, name in found if (why := unresolved(name)) is not None]
    assert wrong == []


def test_an_import_of_a_name_that_moved_is_named():
    (name,) = imported_names("from snac_gym.apps.demo import random_episode_study\n")
    assert unresolved(name) == "snac_gym.apps.demo has no random_episode_study"
