"""One exception base: every exception snac-gym raises on purpose is a SnacGymError (snac_gym/common/errors.py), and the
built-in exception its meaning is closest to, under its old module names too."""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import json
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from snac_gym.common import errors, extras

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
    """A missing optional dependency is named in one form (:func:`snac_gym.common.extras.install_line`'s), and the
    extra it names exists: the forms had drifted apart (``pip install 'snac-gym[rl]'``, ``"snac-gym[check]"``), none
    of them checked against pyproject.toml."""
    import re
    import tomllib

    from snac_gym.common.extras import install_line

    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    named, literal = [], []
    for folder in ("snac_gym", "baselines", "evaluation"):
        for path in (ROOT / folder).rglob("*.py"):
            text, where = path.read_text(), path.relative_to(ROOT).as_posix()
            named += [(where, e) for e in re.findall(r'require(?:_installed)?\(\s*"[\w.]+",\s*"(\w+)"', text)]
            named += [(where, e) for e in re.findall(r"install_line\(\s*[\"'](\w+)[\"']\s*\)", text)]
            literal += [(where, hint) for hint in re.findall(r"pip install [^\n`]*", text)]
    assert len(named) >= 10  # the search finds them
    for where, extra in named:
        assert extra in declared, f"{where}: names the extra {extra!r}, which pyproject.toml does not declare"
    # Written out: the form itself, and the one hard dependency named where its URDFs are missing.
    assert sorted({where for where, _ in literal}) == ["snac_gym/common/extras.py", "snac_gym/model/urdf.py"], literal
    assert install_line("rl") == 'pip install -e ".[rl]"'


@pytest.mark.parametrize(
    ("record", "requirement"),
    [
        (None, "snac-gym[rl]"),  # from a package index: pip writes no direct_url.json
        (
            {"url": "file:///w/snac_gym-0.2.0-py3-none-any.whl", "archive_info": {"hash": "sha256=00"}},
            "snac-gym[rl] @ file:///w/snac_gym-0.2.0-py3-none-any.whl",
        ),
        (
            {"url": "https://github.com/o/snac-gym.git", "vcs_info": {"vcs": "git", "commit_id": "9b1bcfb0"}},
            "snac-gym[rl] @ git+https://github.com/o/snac-gym.git@9b1bcfb0",
        ),
    ],
    ids=["index", "wheel", "git"],
)
def test_an_installed_package_names_the_source_it_came_from_in_its_install_hint(
    tmp_path, monkeypatch, record, requirement
):
    """``pip install -e ".[rl]"`` only works in a checkout: a wheel installed elsewhere names its own source, as pip
    recorded it (``direct_url.json``, PEP 610), in a requirement pip parses."""

    class Distribution:
        def read_text(self, name):
            assert name == "direct_url.json"
            return None if record is None else json.dumps(record)

    monkeypatch.setattr(importlib.metadata, "distribution", lambda name: Distribution())
    source = extras._install_source.__wrapped__(tmp_path)  # site-packages: no pyproject.toml beside snac_gym/
    assert f"snac-gym[rl]{source}" == requirement
    parsed = Requirement(requirement)
    assert parsed.name == "snac-gym" and parsed.extras == {"rl"}
    assert extras._install_source.__wrapped__(ROOT) is None  # the checkout: the README's editable form
    assert extras.install_line("rl") == 'pip install -e ".[rl]"'
