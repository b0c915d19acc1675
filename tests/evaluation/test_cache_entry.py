"""Caches that prove what they hand back (evaluation/cache_entry.py): each fault of an entry of the reference's
and of the calibration cache is named on stderr and computed again, never used; an unwritable cache costs one
warning line, not the run; each cache's key moves with every module its values come from."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, code_graph, run_evaluation
from snac_gym.evaluation.cache_entry import DamagedEntry, entry_text, read_entry, write_entry
from snac_gym.evaluation.code_graph import module_closure
from snac_gym.evaluation.effort import cache as calibration_cache
from snac_gym.evaluation.reference import cache as reference_cache
from snac_gym.evaluation.reference.optimum import run_optimal_job

FAULTS = ("flipped-bit", "empty-object", "wrong-key", "out-of-range", "directory-in-the-way")


# -- the entry format ---------------------------------------------------------------------------------
def test_an_entry_round_trips_bit_for_bit_and_every_edit_is_caught(tmp_path):
    payload = {"cost": 0.1 + 0.2, "nan": float("nan"), "flag": True, "n": 3}
    path = tmp_path / "e.json"
    write_entry(path, "k", payload)
    back = read_entry(path, "k")
    assert back["cost"] == 0.1 + 0.2 and back["flag"] is True and back["nan"] != back["nan"]
    assert read_entry(tmp_path / "absent.json", "k") is None
    text = path.read_text()
    for edited, reason in [
        (text.replace("0.30000000000000004", "0.30000000000000016"), "SHA-256"),  # one digit
        ("{}", "fields missing"),
        ("[1, 2", "not JSON"),
        (entry_text("other", payload), "another key"),
    ]:
        path.write_text(edited)
        with pytest.raises(DamagedEntry, match=reason):
            read_entry(path, "k")


# -- the reference cache ------------------------------------------------------------------------------
@pytest.fixture
def job(reference_job):
    return reference_job


def _damage(path: Path, fault: str, other: Path) -> None:
    if fault == "flipped-bit":  # one bit of one digit of the payload
        data = bytearray(path.read_bytes())
        at = data.index(b'"cost": ') + len(b'"cost": ') + 2
        data[at] ^= 0x01
        path.write_bytes(bytes(data))
    elif fault == "empty-object":
        path.write_text("{}")
    elif fault == "wrong-key":  # another entry's file under this name
        shutil.copyfile(other, path)
    elif fault == "directory-in-the-way":
        path.unlink()
        path.mkdir()


def _fresh(job):
    columns = lambda rows: [c for c in rows.columns if c != "optimal_solve_time"]  # noqa: E731 - wall time differs
    rows = run_optimal_job(dataclasses.replace(job, cache_dir=None)).metrics
    return rows[columns(rows)]


@pytest.mark.parametrize("fault", FAULTS)
def test_a_damaged_reference_entry_is_named_and_solved_again(job, counted_solves, capsys, fault):
    run_optimal_job(job)
    folder = Path(job.cache_dir)
    keys = [reference_cache.sample_key(job, s) for s in job.samples]
    target, other = folder / f"{keys[1]}.json", folder / f"{keys[2]}.json"
    if fault == "out-of-range":  # a valid entry (checksum and key) whose row does not hold: the validation
        entry = json.loads(target.read_text())
        entry["payload"]["cost"] *= 1.5
        write_entry(target, keys[1], entry["payload"])
    else:
        _damage(target, fault, other)
    capsys.readouterr()
    counted_solves.clear()
    solved = counted_solves
    rows = run_optimal_job(job).metrics
    assert solved == [1]  # the damaged sample only
    pd.testing.assert_frame_equal(rows[_fresh(job).columns], _fresh(job), check_exact=True)
    lines = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(lines) == 1 and str(target) in lines[0] and "computing it again" in lines[0], lines


def test_every_float_of_every_reference_entry_scaled_gives_the_fresh_rows(job, counted_solves, capsys):
    """The audit's own fault: every float of every entry ×1.5 (checksums left as they were)."""
    run_optimal_job(job)
    for path in Path(job.cache_dir).glob("*.json"):
        entry = json.loads(path.read_text())
        entry["payload"] = {k: v * 1.5 if isinstance(v, float) else v for k, v in entry["payload"].items()}
        path.write_text(json.dumps(entry))
    counted_solves.clear()
    solved = counted_solves
    rows = run_optimal_job(job).metrics
    assert solved == [3]
    pd.testing.assert_frame_equal(rows[_fresh(job).columns], _fresh(job), check_exact=True)
    assert "damaged entry" in capsys.readouterr().err


@pytest.mark.parametrize("blocker", ["file-in-the-way", "unwritable"])
def test_an_unusable_reference_cache_folder_warns_once_and_the_rows_are_solved(
    job, tmp_path, monkeypatch, capsys, blocker
):
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache folder should be")
    folder = blocked if blocker == "file-in-the-way" else blocked / "reference"  # under a file: cannot be made
    rows = run_optimal_job(dataclasses.replace(job, cache_dir=str(folder))).metrics
    pd.testing.assert_frame_equal(rows[_fresh(job).columns], _fresh(job), check_exact=True)
    lines = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(lines) == 1 and str(folder) in lines[0] and "--no-reference-cache" in lines[0], lines


def test_the_reference_key_covers_every_module_of_its_import_graph_and_moves_with_each(job, monkeypatch):
    """The modules are read off the import graph (tests/evaluation/reference/test_reference_cache.py compares them
    with grimp's), the robots' tables included; an edit of any one of them is another key."""
    modules = set(reference_cache.code_modules())
    assert {"snac_gym.model.robots", "snac_gym.model.ur_models", "snac_gym.model.kinematics",
            "snac_gym.control.trajopt", "snac_gym.kernels.relaxation", "snac_gym.baselines.lqr",
            "snac_gym.model.joint_goal"} <= modules  # fmt: skip
    before = reference_cache.sample_key(job, job.samples[0])
    real_read = Path.read_bytes
    for module in sorted(modules):
        origin = Path(__import__("importlib").util.find_spec(module).origin)
        monkeypatch.setattr(
            Path, "read_bytes", lambda self, _o=origin: real_read(self) + (b"\n# edited" if self == _o else b"")
        )
        reference_cache.code_fingerprint.cache_clear()
        assert reference_cache.sample_key(job, job.samples[0]) != before, module
    monkeypatch.setattr(Path, "read_bytes", real_read)
    reference_cache.code_fingerprint.cache_clear()
    assert reference_cache.sample_key(job, job.samples[0]) == before


def test_the_statement_walk_finds_every_import_that_a_walk_of_every_node_finds():
    """:func:`code_graph._statements` visits the blocks only; on every module of the package, and on a module with
    imports in every kind of block, it finds the same import statements as :func:`ast.walk`."""
    import ast

    import snac_gym.baselines
    import snac_gym.evaluation
    from snac_gym.evaluation import code_graph

    tricky = ast.parse(
        "import a\nif x:\n    import b\nelse:\n    import c\ntry:\n    import d\nexcept E:\n    import e\n"
        "else:\n    import f\nfinally:\n    import g\nwith w:\n    import h\nfor i in y:\n    import i\n"
        "else:\n    import j\nwhile z:\n    import k\nclass C:\n    def m(self):\n        import l\n"
        "async def n():\n    async with v:\n        import o\n    async for p in q:\n        import p\n"
        "match s:\n    case 1:\n        import r\n"
    )
    folders = {Path(package.__file__).parent for package in (snac_gym, snac_gym.evaluation, snac_gym.baselines)}
    sources = [tricky] + [ast.parse(path.read_text()) for folder in folders for path in sorted(folder.rglob("*.py"))]
    assert len(sources) > 150
    for tree in sources:
        every = [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
        blocks = [node for node in code_graph._statements(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
        assert sorted(map(id, blocks)) == sorted(map(id, every))
    assert len([n for n in code_graph._statements(tricky) if isinstance(n, ast.Import)]) == 15


def test_the_import_graph_follows_relative_and_in_function_imports():
    closure = module_closure(["snac_gym.model.joint_goal"])
    assert "snac_gym.kernels.small" in closure  # imported inside a function
    assert "snac_gym.kernels.compiled" in closure  # ... and what that module imports
    assert closure == tuple(sorted(closure)) and "snac_gym.evaluation.runner" not in closure


def test_reading_the_graph_runs_no_module_it_reaches(tmp_path, monkeypatch):
    """An import names a module's attribute as often as a module (``from a.b import C``): looking for a module ``C``
    must not run ``a.b``. The reference's key imported MuJoCo in every worker so."""
    package = tmp_path / "snac_gym_probe"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "leaf.py").write_text("import sys\nsys.modules['snac_gym_probe_ran'] = None\nThing = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert code_graph._origin("snac_gym_probe.sub.leaf.Thing") is None  # an attribute of a plain module
    assert code_graph._origin("snac_gym_probe.sub.leaf") == package / "sub" / "leaf.py"
    assert code_graph._origin("snac_gym_probe.sub") == package / "sub" / "__init__.py"
    assert "snac_gym_probe_ran" not in sys.modules and "snac_gym_probe.sub.leaf" not in sys.modules
    # the reference's key, in a process that has imported what a worker has: nothing more is imported
    script = (
        "import sys\nimport snac_gym.evaluation.reference.optimum\nfrom snac_gym.evaluation.reference import cache\n"
        "before = set(sys.modules)\ncache.code_fingerprint()\n"
        "print(sorted(m for m in set(sys.modules) - before if m.startswith(('snac_gym', 'mujoco'))))\n"
        "print('snac_gym.physics.mujoco' in cache.code_modules())"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=120)
    assert result.stdout.split("\n")[:2] == ["[]", "True"], result.stdout + result.stderr


# -- the calibration cache ----------------------------------------------------------------------------
SMALL = {"tasks": ("reach",), "horizons": {"reach": 0.4}, "controllers": ("snac", "lqr"), "chunk_size": 4,
         "progress": False, "plots": False, "samples": 3, "effort_samples": 8}  # fmt: skip


@pytest.fixture
def calibration_on(tmp_path, monkeypatch):
    monkeypatch.setenv(calibration_cache.SWITCH_ENV, "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "calibration"


def _evaluate(tmp_path, name):
    rows = run_evaluation(EvaluationConfig(out=tmp_path / name, **SMALL))
    timings = json.loads((tmp_path / name / "timings.json").read_text())
    return rows, ("effort matching" in timings)


@pytest.mark.parametrize("fault", FAULTS)
def test_a_damaged_calibration_entry_is_named_and_matched_again(calibration_on, tmp_path, capsys, fault):
    first, matched = _evaluate(tmp_path, "first")
    assert matched
    entries = sorted(calibration_on.glob("*.json"))
    assert len(entries) == 2
    lqr = next(p for p in entries if json.loads(p.read_text())["payload"]["record"]["controller"] == "lqr")
    other = next(p for p in entries if p != lqr)
    if fault == "out-of-range":  # a valid entry whose record does not hold: a knob that is no knob
        entry = json.loads(lqr.read_text())
        entry["payload"]["record"]["knob_value"] = -1.0
        write_entry(lqr, entry["key"], entry["payload"])
    else:
        _damage_record(lqr, fault, other)
    capsys.readouterr()
    again, matched = _evaluate(tmp_path, "again")
    assert matched  # matched anew, not read
    pd.testing.assert_frame_equal(again, first, check_exact=True)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning")]
    assert len(lines) == 1 and str(lqr) in lines[0], lines
    assert json.loads(lqr.read_text())["payload"]["record"]["controller"] == "lqr"  # overwritten by the new match


def _damage_record(path: Path, fault: str, other: Path) -> None:
    if fault == "flipped-bit":
        data = bytearray(path.read_bytes())
        at = data.index(b'"knob_value": ') + len(b'"knob_value": ') + 1
        data[at] ^= 0x01
        path.write_bytes(bytes(data))
    else:
        _damage(path, fault, other)


def test_every_float_of_every_calibration_entry_scaled_gives_the_fresh_rows(calibration_on, tmp_path):
    first, _ = _evaluate(tmp_path, "first")

    def scaled(value):
        if isinstance(value, float):
            return value * 1.5
        if isinstance(value, dict):
            return {k: scaled(v) for k, v in value.items()}
        return value

    for path in calibration_on.glob("*.json"):
        entry = json.loads(path.read_text())
        path.write_text(json.dumps({**entry, "payload": scaled(entry["payload"])}))
    again, matched = _evaluate(tmp_path, "again")
    assert matched
    pd.testing.assert_frame_equal(again, first, check_exact=True)


@pytest.mark.parametrize("blocker", ["file-in-the-way", "unwritable"])
def test_an_unwritable_calibration_folder_warns_once_and_the_run_ends_with_the_same_rows(
    tmp_path, monkeypatch, capsys, blocker
):
    monkeypatch.setenv(calibration_cache.SWITCH_ENV, "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "fine"))
    reference, _ = _evaluate(tmp_path, "reference")
    blocked = tmp_path / "blocked"
    blocked.write_text("a file")
    # file-in-the-way: the calibration folder is a file; unwritable: the cache root lies under a file
    if blocker == "file-in-the-way":
        (tmp_path / "root").mkdir()
        shutil.copyfile(blocked, tmp_path / "root" / "calibration")
        monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "root"))
    else:
        monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(blocked / "cache"))
    capsys.readouterr()
    rows, matched = _evaluate(tmp_path, "blocked-run")
    assert matched
    pd.testing.assert_frame_equal(rows, reference, check_exact=True)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning")]
    assert len(lines) == 1 and calibration_cache.SWITCH_ENV in lines[0], lines
