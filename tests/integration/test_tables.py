"""The README's and docs' tables of ids, spaces, robots and controllers are what tools/tables.py writes from the
registries; the v0/v1 text matches the registered spaces; no training command names a -v0 id."""

from __future__ import annotations

import importlib.util
import re
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.model.robots import robot_names
from snac_gym.policies import available_policies

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


@pytest.fixture(scope="module")
def tables():
    spec = importlib.util.spec_from_file_location("tables", ROOT / "tools" / "tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_tables_regenerate_to_themselves(tables, capsys):
    assert tables.main(["--check"]) == 0, capsys.readouterr().err
    for path in tables.TARGETS:  # every writer has its place, and nothing else is marked
        assert {m["name"] for m in tables._BLOCK.finditer(path.read_text())} == set(tables.BLOCKS[path.name])


def test_every_registered_controller_and_robot_is_named_in_the_readme():
    text = README.read_text(encoding="utf-8")
    for name in available_policies():
        assert f"| `{name}` |" in text, name
    for name in robot_names():
        assert f"`{name}` (" in text, name


def test_an_edited_table_fails_the_check_naming_it(tables, tmp_path, monkeypatch, capsys):
    readme = tmp_path / "README.md"
    shutil.copyfile(README, readme)
    readme.write_text(readme.read_text().replace("| `mpc` |", "| `mpc2` |", 1))
    monkeypatch.setattr(tables, "ROOT", tmp_path)
    monkeypatch.setattr(tables, "TARGETS", (readme,))
    assert tables.main(["--check"]) == 1
    assert "README.md: controllers is stale" in capsys.readouterr().err
    assert "`mpc2`" in readme.read_text()  # --check writes nothing


def test_a_controller_registered_without_prose_stops_the_writer_naming_it(tables, monkeypatch):
    from snac_gym.policies import registry

    monkeypatch.setitem(registry._FACTORIES, "my-controller", lambda env: None)
    with pytest.raises(SystemExit, match=r"no prose for the controller \['my-controller'\]"):
        tables.controllers(lambda page: page)()
    monkeypatch.delitem(registry._FACTORIES, "my-controller")
    monkeypatch.setitem(tables.CONTROLLERS, "gone", ("x", "y", "z.md"))
    with pytest.raises(SystemExit, match=r"the controller \['gone'\] is not registered"):
        tables.controllers(lambda page: page)()


def _spaces_rows(text: str) -> dict[str, list[str]]:
    block = text.split("<!-- tables:spaces -->\n", 1)[1].split("<!-- /tables:spaces -->", 1)[0]
    rows = [line.strip("|").split(" | ") for line in block.strip().splitlines()[2:]]
    return {row[0].strip(" `"): [cell.strip() for cell in row[1:]] for row in rows}


@pytest.mark.parametrize("page", ["README.md", "docs/environments.md"])
def test_the_v0_v1_text_matches_the_registered_spaces(page):
    """Read apart from the writer: each family's row against the spaces of its registered ids, both versions."""
    rows = _spaces_rows((ROOT / page).read_text(encoding="utf-8"))
    assert len(rows) == 6
    for family, cells in rows.items():
        for version, (action, observation) in zip((1, 0), (cells[:2], cells[2:])):
            robot = "Panda" if "Coarse" in family else "UR10"
            env = gym.make(f"snac_gym/{family.replace('<Robot>', robot)}-v{version}", physics="kinematic")
            space = env.action_space
            assert str(space.dtype) in action and f"({space.shape[0]},)" in action or "(m,)" in action
            normalized = np.all(space.low == -1) and np.all(space.high == 1)
            assert ("−1, 1" in action) == normalized, (family, version, action)
            boxes = list(env.observation_space.values()) if "Goal" in family else [env.observation_space]
            assert ("Dict" in observation) == ("Goal" in family)
            for box in boxes:
                assert str(box.dtype) in observation, (family, version, observation)
            infinite = any(not np.isfinite(box.high).all() for box in boxes)
            assert ("±inf" in observation) == infinite, (family, version, observation)
            env.close()


#: A command or call that trains: rl-zoo3, the CLI's PPO training, the SAC+HER script, SB3's learn().
TRAINING = re.compile(r"rl_zoo3\.train|train-ppo|sac_her_reach\.py|\.learn\(")
V0_ID = re.compile(r"snac_gym/\w+-v0\b")


def _commands(path: Path) -> list[tuple[int, str]]:
    """The training commands of a page: each line that trains with the lines continuing it (``\\``), or, in a
    fenced block or an example script, the whole block or file when it trains."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".py":
        return [(1, text)] if TRAINING.search(text) else []
    found = []
    for match in re.finditer(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M):
        if TRAINING.search(match[1]):
            found.append((text[: match.start()].count("\n") + 1, match[1]))
    prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.S | re.M)
    for number, line in enumerate(prose.splitlines(), 1):
        for command in re.findall(r"`([^`]+)`", line):
            if TRAINING.search(command):
                found.append((number, command))
    return found


def test_no_training_command_names_a_v0_id():
    pages = [README, *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "examples").glob("*.py"))]
    pages.append(ROOT / "docs" / "scripts" / "sac_her_reach.py")  # the README's SAC+HER command runs it
    commands = [(path, line, text) for path in pages for line, text in _commands(path)]
    assert len(commands) >= 8  # the README's rl-zoo3 command, docs/rl.md's, the examples
    offending = [f"{path.relative_to(ROOT)}:{line}" for path, line, text in commands if V0_ID.search(text)]
    assert not offending, f"training on a -v0 id (train on -v1): {offending}"
