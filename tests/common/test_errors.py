"""One exception base: every exception snac-gym raises on purpose is a SnacGymError (snac_gym/common/errors.py), and the
built-in exception its meaning is closest to, under its old module names too."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from snac_gym.common import errors

ROOT = Path(__file__).resolve().parents[2]
OLD_HOMES = {
    "snac_gym.common.outputs": ["OutputFolderError", "OutputWriteError"],
    "snac_gym.rollout.batch": ["RolloutError"],
    "snac_gym.real.emulator.protocol": ["ProtocolError"],
    "snac_gym.real.connections": ["ConnectionFailure"],
    "snac_gym.ppo.config": ["ConfigError"],
    "snac_gym.ppo.policy_file": ["PolicyFileError", "MissingPolicyFileError"],
    "snac_gym.common.extras": ["MissingExtraError"],
    "snac_gym.evaluation.samples": ["SampleFileError"],
    "snac_gym.evaluation.cache_entry": ["DamagedEntry"],
    "snac_gym.evaluation.store": ["RunDirectoryError"],
    "snac_gym.evaluation.execution.executors": ["ExecutorStopped"],
    "snac_gym.evaluation.execution.passes": ["Cancelled"],
}


@pytest.mark.parametrize("name", [n for n in errors.__all__ if n != "SnacGymError"])
def test_every_exception_is_a_snac_gym_error(name):
    assert issubclass(getattr(errors, name), errors.SnacGymError)


@pytest.mark.parametrize("module", sorted(OLD_HOMES))
def test_the_old_names_are_the_same_classes(module):
    loaded = importlib.import_module(module)
    for name in OLD_HOMES[module]:
        assert getattr(loaded, name) is getattr(errors, name)


def test_no_public_exception_class_is_defined_outside_errors_py():
    found = []
    for path in [*ROOT.joinpath("snac_gym").rglob("*.py"), *ROOT.joinpath("evaluation").rglob("*.py"),
                 *ROOT.joinpath("baselines").rglob("*.py")]:  # fmt: skip
        if path.name == "errors.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                bases = {getattr(b, "id", getattr(b, "attr", "")) for b in node.bases}
                if bases & {"Exception", "ValueError", "RuntimeError", "OSError", "ConnectionError", "ImportError"}:
                    found.append(f"{path.relative_to(ROOT)}: {node.name}")
    assert found == [], found


def test_every_install_hint_names_an_extra_the_package_declares():
    """A missing optional dependency is named in one form (:func:`snac_gym.common.extras.require`'s), and the extra
    it names exists: the forms had drifted apart (``pip install 'snac-gym[rl]'``, ``"snac-gym[check]"``), none of
    them checked against pyproject.toml."""
    import re
    import tomllib

    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    dependencies = {"example-robot-data"}  # a hard dependency of the package, named where its URDFs are missing
    hints, required = [], []
    for folder in ("snac_gym", "baselines", "evaluation"):
        for path in (ROOT / folder).rglob("*.py"):
            text, where = path.read_text(), path.relative_to(ROOT).as_posix()
            hints += [(where, hint) for hint in re.findall(r"pip install [^\n)]*", text)]
            required += [
                (where, extra) for extra in re.findall(r'require(?:_installed)?\(\s*"[\w.]+",\s*"(\w+)"', text)
            ]
    assert len(hints) >= 5 and len(required) >= 10  # the searches find them
    for where, extra in required:
        assert extra in extras, f"{where}: require(..., {extra!r}, ...) names no extra of pyproject.toml"
    for where, hint in hints:
        named = re.match(r'pip install -e \\?"\.\[([^\]]+)\]', hint)
        if named is None:
            assert any(name in hint for name in dependencies), f'{where}: {hint!r} is not `pip install -e ".[EXTRA]"`'
        elif named.group(1) not in ("{extra}", "<extra>"):  # but the generic line itself (extras.require)
            assert named.group(1) in extras, f"{where}: {hint!r} names no extra of pyproject.toml"
