"""The optimal reference's rows, cached on disk by sample content.

The reference depends on a sample (θ₀ and its reference), the horizon, Δt, the cost convention, the
arm and its constraints, and on the code that computes it: never on the run's controllers. A row
computed once is therefore valid for every later run with the same inputs, whatever its seed, sample
id, sample count or workers. Each entry is one JSON file named by the SHA-256 of all of those inputs,
the code included (the source of every module the solve reads, found by following its imports:
:mod:`snac_gym.evaluation.code_graph`; the package data it reads; and the versions of NumPy, SciPy and Pinocchio), so
that a changed solver, cost, kinematics or robot never reuses a stale row. An entry holds its key and the SHA-256 of
its row, and a row read back is validated as a fresh one is; a damaged entry is named on stderr and solved again
(:mod:`snac_gym.evaluation.cache_entry`). A folder that cannot be written is named once, and the run goes on.

The folder is ``$SNAC_GYM_CACHE_DIR/reference`` (default ``~/.cache/snac-gym/reference``, or under
``$XDG_CACHE_HOME``); ``--no-reference-cache`` solves every sample anew. JSON keeps every float bit for
bit (``repr``), NaN included, so a cached row equals the computed one exactly.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import pickle
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.cache_entry import CacheWarnings, DamagedEntry, read_entry, write_entry
from snac_gym.evaluation.code_graph import module_closure, sources_fingerprint

from snac_gym.common.cache_dir import CACHE_ENV, cache_root
from snac_gym.control.jacobian_bound import SHIPPED as JACOBIAN_BOUNDS

#: Where the reference's code starts: its module, and the modules of the feedback laws it starts from (made by their
#: registered names, so not in its import graph), which the reference adds when it is imported (:func:`add_roots`).
ROOTS: list[str] = ["snac_gym.evaluation.reference.optimum"]


def add_roots(modules: Sequence[str]) -> None:
    """Add modules whose code the rows depend on but the import graph does not reach (called by name)."""
    for module in modules:
        if module not in ROOTS:
            ROOTS.append(module)
    code_fingerprint.cache_clear()


#: Distributions whose version is part of the key (their numerics shape the rows).
DISTRIBUTIONS = ("numpy", "scipy", "pin", "example-robot-data", "numba")
#: Package data the rows depend on, read by the code rather than imported: the shipped bounds on ‖J‖₂ (the lower
#: bound's column).
DATA_FILES = (JACOBIAN_BOUNDS,)


def cache_folder() -> Path:
    """The reference's rows: ``reference`` under :func:`cache_root`."""
    return cache_root() / "reference"


def code_modules() -> tuple[str, ...]:
    """Every module of the package the reference's rows depend on: the import graph from :data:`ROOTS`
    (:func:`snac_gym.evaluation.code_graph.module_closure`)."""
    return module_closure(ROOTS)


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of the source of :func:`code_modules`, the contents of :data:`DATA_FILES` and the versions of
    :data:`DISTRIBUTIONS`."""
    digest = hashlib.sha256(sources_fingerprint(code_modules()).encode())
    for name in DATA_FILES:
        data = resources.files("snac_gym").joinpath(name)
        digest.update(data.read_bytes() if data.is_file() else b"missing")
    add_versions(digest, DISTRIBUTIONS)
    return digest.hexdigest()


def installed_versions(distributions: Sequence[str]) -> dict[str, str]:
    """The version of each distribution, ``missing`` where it is not installed."""
    found = {}
    for name in distributions:
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            found[name] = "missing"
    return found


def add_versions(digest: Any, distributions: Sequence[str]) -> None:
    """Feed ``name==version`` of each distribution (:func:`installed_versions`) to ``digest``."""
    for name, version in installed_versions(distributions).items():
        digest.update(f"{name}=={version}".encode())


def sample_key(job: Any, sample: Any) -> str:
    """The entry's name: every input of one sample's reference row (not its id or seed)."""
    content = (
        job.task,
        job.robot,
        int(job.steps),
        float(job.dt).hex(),
        job.convention,
        bool(job.position_limits),
        float(job.screen_margin).hex(),
        tuple(float(angle).hex() for angle in np.asarray(sample.q0, dtype=float)),
        sample.reference,
        code_fingerprint(),
    )
    return hashlib.sha256(pickle.dumps(content, protocol=5)).hexdigest()


#: The reference cache's warnings: a damaged entry, an unwritable folder (one line each, on stderr).
WARNINGS = CacheWarnings("the reference cache", f"--no-reference-cache, or {CACHE_ENV} at a writable folder")


def read_rows(
    folder: Path, keys: Sequence[str], check: Callable[[dict[str, Any]], None] | None = None
) -> list[dict[str, Any] | None]:
    """Each key's cached row (without ``sample``), or ``None`` where there is none, or it is damaged: unreadable,
    of another key, not matching its checksum, or refused by ``check`` (the validation of a fresh row). A damaged
    entry is named on stderr (:data:`WARNINGS`) and solved again."""
    rows: list[dict[str, Any] | None] = []
    if folder.exists() and not folder.is_dir():
        WARNINGS.unwritable(folder, NotADirectoryError(20, "a file is in the way of the folder"))
        return [None] * len(keys)
    damaged: list[DamagedEntry] = []
    for key in keys:
        path = folder / f"{key}.json"
        try:
            row = read_entry(path, key)
            if row is not None:
                if not isinstance(row, dict):
                    raise DamagedEntry(path, "its value is not a row")
                if check is not None:
                    try:
                        check(row)
                    except (ValueError, KeyError, TypeError) as exc:
                        raise DamagedEntry(path, f"its row does not hold ({exc})") from None
        except DamagedEntry as problem:
            damaged.append(problem)
            row = None
        rows.append(row)
    WARNINGS.damaged(damaged)
    return rows


def write_rows(folder: Path, keys: Sequence[str], rows: pd.DataFrame) -> None:
    """Store each row under its key, atomically (a file is whole or absent), with its key and checksum
    (:mod:`snac_gym.evaluation.cache_entry`). A folder that cannot be written costs later runs a solve, not this
    one: it is named once on stderr and the run goes on."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for key, record in zip(keys, rows.drop(columns=["sample"]).to_dict("records"), strict=True):
            write_entry(folder / f"{key}.json", key, {name: _plain(value) for name, value in record.items()})
    except OSError as exc:
        WARNINGS.unwritable(folder, exc)


def _plain(value: Any) -> Any:
    """A NumPy scalar as the Python value JSON writes exactly (floats by ``repr``)."""
    return value.item() if isinstance(value, np.generic) else value


__all__ = [
    "CACHE_ENV",
    "ROOTS",
    "WARNINGS",
    "add_roots",
    "cache_folder",
    "cache_root",
    "code_fingerprint",
    "code_modules",
    "read_rows",
    "sample_key",
    "write_rows",
]
