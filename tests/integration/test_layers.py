"""The package's structure: import names, layers, cycles and live registries.

``tools/lint_imports.py`` (in the README's test command) checks pyproject.toml's import-linter contracts and
counts import cycles; here it is shown to pass on the package and to fail on a planted violation of each kind.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Each installed package with a folder of its own, as pyproject.toml's package-dir maps them.
FOLDERS = {
    "snac_gym": ROOT / "snac_gym",
    "snac_gym.baselines": ROOT / "baselines",
    "snac_gym.evaluation": ROOT / "evaluation",
}
TOOL = ROOT / "tools" / "lint_imports.py"
sys.path.insert(0, str(TOOL.parent))
from lint_imports import lay_out  # noqa: E402


def _check(tree: Path | None = None) -> subprocess.CompletedProcess:
    args = [sys.executable, str(TOOL)] + ([] if tree is None else ["--tree", str(tree)])
    return subprocess.run(args, capture_output=True, text=True, timeout=120)


def _plant(tree: Path, module: str, line: str) -> None:
    """Replace the link of ``module`` (a file directly under a linked folder's parent) by a copy with ``line`` added."""
    parts = module.split(".")
    folder = tree.joinpath(*parts[:-1])
    if folder.is_symlink():  # a linked package: lay out its entries one by one
        target = folder.resolve()
        folder.unlink()
        folder.mkdir()
        for entry in target.iterdir():
            (folder / entry.name).symlink_to(entry)
    path = folder / f"{parts[-1]}.py"
    text = path.read_text()
    path.unlink()
    path.write_text(text + f"\n{line}\n")


def test_the_package_keeps_its_layers_and_has_no_import_cycle():
    result = _check()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "3 kept, 0 broken" in result.stdout
    assert "import cycles: 0" in result.stdout


def test_a_core_module_importing_the_harness_breaks_the_layers_contract(tmp_path):
    tree = lay_out(ROOT, tmp_path / "tree")
    _plant(tree, "snac_gym.control.cost", "import snac_gym.evaluation.runner  # planted")
    result = _check(tree)
    assert result.returncode == 1
    assert "BROKEN" in result.stdout
    assert "snac_gym.control.cost -> snac_gym.evaluation.runner" in result.stdout


def test_an_import_inside_a_function_counts(tmp_path):
    tree = lay_out(ROOT, tmp_path / "tree")
    _plant(tree, "snac_gym.physics.kinematic", "def _late():\n    from snac_gym.envs import core  # planted")
    result = _check(tree)
    assert result.returncode == 1
    assert "snac_gym.physics.kinematic -> snac_gym.envs.core" in result.stdout


def test_a_cycle_inside_one_layer_is_found(tmp_path):
    """robots and references share the core layer, so only the cycle check can catch this one."""
    tree = lay_out(ROOT, tmp_path / "tree")
    _plant(tree, "snac_gym.references", "import snac_gym.model.robots  # planted")
    result = _check(tree)
    assert result.returncode == 1
    assert "3 kept, 0 broken" in result.stdout
    assert "import cycle: snac_gym.model.robots -> snac_gym.references -> snac_gym.model.robots" in result.stdout
    assert "import cycles: 1" in result.stdout


def _contract_modules() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (layers,) = [c for c in config["contracts"] if c["type"] == "layers"]
    return [name.strip() for layer in layers["layers"] for group in layer.split("|") for name in group.split(":")]


def _modules() -> list[str]:
    """Every module of the installed package, read from the folders as pyproject.toml maps them."""
    found = []
    for package, folder in FOLDERS.items():
        for path in folder.rglob("*.py"):
            parts = path.relative_to(folder).with_suffix("").parts
            name = ".".join((package, *parts))
            if name.removesuffix(".__init__") not in FOLDERS or package == "snac_gym":
                found.append(name.removesuffix(".__init__"))
    return sorted(set(found))


def test_every_module_belongs_to_a_layer():
    """A new module cannot escape the contract by sitting outside every layer."""
    layers = _contract_modules()
    outside = [
        m
        for m in _modules()
        if m != "snac_gym" and not any(m == layer or m.startswith(layer + ".") for layer in layers)
    ]
    assert outside == []


def test_pyproject_lists_every_package():
    """pyproject.toml lists the packages by hand (package-dir maps two folders): none may be left out."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    packages = {
        ".".join((package, *init.parent.relative_to(folder).parts))
        for package, folder in FOLDERS.items()
        for init in folder.rglob("__init__.py")
    }
    assert packages == listed


def _package_folder(package: str) -> Path:
    """Where ``package`` lives in the repository, as pyproject.toml's package-dir maps it."""
    top = max((p for p in FOLDERS if package == p or package.startswith(p + ".")), key=len)
    rest = package.removeprefix(top).lstrip(".")
    return FOLDERS[top].joinpath(*rest.split(".")) if rest else FOLDERS[top]


def _data_files(root: Path) -> set[Path]:
    """Every file of the package folders under ``root`` that is not Python source or a cache."""
    found = set()
    for folder in FOLDERS.values():
        for path in (root / folder.relative_to(ROOT)).rglob("*"):
            if path.is_file() and path.suffix not in (".py", ".pyc") and "__pycache__" not in path.parts:
                found.add(path.relative_to(root))
    return found


def _shipped(root: Path) -> set[Path]:
    """The files pyproject.toml's package-data globs pick, each relative to its package's folder, as setuptools
    globs them for a wheel."""
    data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    return {
        path.relative_to(root)
        for package, patterns in data.items()
        for pattern in patterns
        for path in (root / _package_folder(package).relative_to(ROOT)).glob(pattern)
        if path.is_file()
    }


def test_every_data_file_of_the_package_ships_in_the_wheel():
    """An editable install reads a data file from the repository whatever pyproject.toml says, so the suite would pass
    while ``pip install .`` left the file out (shipped knobs, PPO weights, URDFs, the zoo's files): every non-Python
    file in the package folders must match a package-data glob."""
    files = _data_files(ROOT)
    assert any(p.suffix == ".npz" for p in files) and any(p.suffix == ".urdf" for p in files)  # the walk finds them
    assert sorted(map(str, files - _shipped(ROOT))) == []


def test_a_data_file_no_glob_picks_is_named(tmp_path):
    """The check fails where it should: a knobs file one folder deeper than ``data/calibration/*.json`` picks."""
    (tmp_path / "snac_gym/data").mkdir(parents=True)
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    shutil.copytree(ROOT / "snac_gym/data/zoo", tmp_path / "snac_gym/data/zoo")  # shipped: not named
    (tmp_path / "snac_gym/data/calibration/extra").mkdir(parents=True)
    (tmp_path / "snac_gym/data/calibration/extra/knobs.json").write_text("{}")
    unshipped = _data_files(tmp_path) - _shipped(tmp_path)
    assert unshipped == {Path("snac_gym/data/calibration/extra/knobs.json")}


@pytest.mark.parametrize("name", ["baselines", "evaluation"])
def test_the_generic_top_level_names_are_not_installed(tmp_path, name):
    """Outside the repository, ``import baselines`` finds nothing; ``snac_gym.baselines`` is the import name."""
    missing = subprocess.run([sys.executable, "-c", f"import {name}"], cwd=tmp_path, capture_output=True, text=True)
    assert missing.returncode == 1
    assert f"No module named '{name}'" in missing.stderr
    found = subprocess.run(
        [sys.executable, "-c", f"import snac_gym.{name}"], cwd=tmp_path, capture_output=True, text=True
    )
    assert found.returncode == 0, found.stderr


@pytest.mark.parametrize("name", ["baselines", "evaluation"])
def test_the_old_import_from_the_repository_says_what_to_write(name):
    """From the repository's root the folder is on the path: importing it under the old name is refused clearly."""
    result = subprocess.run([sys.executable, "-c", f"import {name}"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 1
    assert f"snac-gym's {name} package is imported as snac_gym.{name} since 0.2.0" in result.stderr


def test_no_module_copies_a_registry_at_import():
    """No module-level name is bound to a copy of the task or robot registry (tuple(TASKS), list(ROBOTS), ...).

    The CLI's help text is the exception: it is written once per command, when the entry points are loaded.
    """
    copies = []
    for module in _modules():
        if module == "snac_gym.apps.cli":
            continue
        path = _path_of(module)
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
                text = ast.unparse(node.value)
                if any(f"{name}(" in text for name in ("task_names", "robot_names", "all_tasks", "all_robots")) or any(
                    f"{wrap}({registry}" in text
                    for wrap in ("tuple", "list", "dict", "set", "sorted")
                    for registry in ("TASKS", "ROBOTS", "TASK_REGISTRY")
                ):
                    copies.append(f"{module}:{node.lineno}: {ast.unparse(node)[:80]}")
    assert copies == []


def _path_of(module: str) -> Path:
    parts = module.split(".")
    base = {"baselines": ROOT / "baselines", "evaluation": ROOT / "evaluation"}.get(parts[1] if len(parts) > 1 else "")
    folder, rest = (base, parts[2:]) if base is not None else (ROOT / "snac_gym", parts[1:])
    path = folder.joinpath(*rest)
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def test_the_layers_drawing_of_the_docs_is_generated_from_the_code():
    result = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "layers_doc.py"), "--check"], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("old", ["evaluation.runner", "baselines"])
def test_an_old_import_after_snac_gym_names_the_new_one(tmp_path, old):
    """For the 0.2 releases, 0.1.0's import names fail naming where they went (once snac_gym is imported)."""
    top = old.split(".")[0]  # Python imports the parent package first
    result = subprocess.run(
        [sys.executable, "-c", f"import snac_gym, {old}"], cwd=tmp_path, capture_output=True, text=True
    )
    assert result.returncode == 1
    assert f"ModuleNotFoundError: No module named {top!r}: snac-gym's {top} package is imported as" in result.stderr
    assert f"write `import snac_gym.{top}`" in result.stderr


def test_every_moved_root_module_still_imports_as_the_same_module_with_a_warning():
    script = (
        "import importlib, warnings, snac_gym\n"
        "from snac_gym.common._renamed import MOVED\n"
        "for old, new in MOVED.items():\n"
        "    with warnings.catch_warnings(record=True) as seen:\n"
        "        warnings.simplefilter('always')\n"
        "        module = importlib.import_module(old)\n"
        "    assert module is importlib.import_module(new), (old, new)\n"
        "    assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in seen), old\n"
        "print(len(MOVED))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "18", done.stderr
