"""The drawn samples, cached on disk by what they are drawn from.

Sample ``i`` of a task is a function of the seed, the task, ``i``, the arm, the sample space and the code that draws it
(:mod:`snac_gym.evaluation.samples`), and of nothing a run chooses besides. Drawing is a run's first step, the same in
every run at the same settings, and not cheap: each tracking sample solves the arm's inverse kinematics around its
ellipse (Table I's 2000 samples take seconds on 2 cores, most of a warm run's time outside the passes). A run reads
the chunks drawn before and draws only the others.

Each entry is one chunk of consecutive samples of one task, one JSON file named by the SHA-256 of all of those inputs:
the seed, the task, the chunk's indices, the sample space, the arm (its registry entry and its URDF's bytes) and the
code (the source of every module of the package that drawing reads, found by following its imports:
:mod:`snac_gym.evaluation.code_graph`, and the versions of NumPy, SciPy, Pinocchio and example-robot-data). A task
registered by another package (or a built-in one given state of its own) is drawn by what this key cannot follow,
and is not cached. The payload is each sample's CSV cells (:func:`~snac_gym.evaluation.samples.sample_row`: floats by
``repr``, so they read back bit for bit); an entry holds its key and checksum (:mod:`snac_gym.evaluation.cache_entry`),
and a damaged one is named on stderr and drawn again.

The folder is ``$SNAC_GYM_CACHE_DIR/samples`` (default ``~/.cache/snac-gym/samples``, or under ``$XDG_CACHE_HOME``);
``SNAC_GYM_SAMPLE_CACHE=0`` turns it off.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from snac_gym.evaluation.cache_entry import CacheWarnings, DamagedEntry, read_entry, write_entry
from snac_gym.evaluation.code_graph import module_closure, sources_fingerprint
from snac_gym.evaluation.reference.cache import add_versions
from snac_gym.evaluation.samples import EvaluationSample, RowReader, sample_row

from snac_gym.common.cache_dir import CACHE_ENV, cache_root, switched_on
from snac_gym.model.robots import get_robot
from snac_gym.model.urdf import robot_urdf_path
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

#: Environment variable that turns the cache off (``0``, ``off``, ``false`` or ``no``).
SWITCH_ENV = "SNAC_GYM_SAMPLE_CACHE"
#: Distributions whose version is part of the key (their numerics draw the samples).
DISTRIBUTIONS = ("numpy", "scipy", "pin", "example-robot-data")
#: Where the drawing code starts; each cached task's own module is added to it.
ROOTS = ("snac_gym.evaluation.samples",)
#: The cache's warnings: a damaged entry, an unwritable folder (one line each, on stderr).
WARNINGS = CacheWarnings("the sample cache", f"{SWITCH_ENV}=0, or {CACHE_ENV} at a writable folder")


def cache_enabled() -> bool:
    """Whether :data:`SWITCH_ENV` leaves the cache on (it is, unless set to ``0``, ``off``, ``false`` or ``no``)."""
    return switched_on(SWITCH_ENV)


def cache_folder() -> Path:
    """The drawn samples: ``samples`` under :func:`~snac_gym.common.cache_dir.cache_root`."""
    return cache_root() / "samples"


def cacheable(task: str) -> bool:
    """Whether ``task``'s samples are drawn by the package's own code alone: an instance of one of its task classes
    with no state of its own (a task of another package, or one given attributes after it was made, is not cached:
    the key does not follow what draws it)."""
    registered = get_task(task)
    return type(registered).__module__.startswith("snac_gym.") and not getattr(registered, "__dict__", {})


@functools.lru_cache(maxsize=None)
def code_fingerprint(task_module: str) -> str:
    """SHA-256 of the drawing code of a task defined in ``task_module`` (:data:`ROOTS` and that module, with every
    module of the package they import) and the versions of :data:`DISTRIBUTIONS`."""
    digest = hashlib.sha256(sources_fingerprint(module_closure((*ROOTS, task_module))).encode())
    add_versions(digest, DISTRIBUTIONS)
    return digest.hexdigest()


@functools.lru_cache(maxsize=None)
def _arm(robot: str) -> tuple[str, str]:
    """The arm as drawing sees it: its registry entry and its URDF's SHA-256."""
    return repr(get_robot(robot)), hashlib.sha256(robot_urdf_path(robot).read_bytes()).hexdigest()


def _exact(value: Any) -> Any:
    """``value`` with every float as its hex form (``repr`` of an array rounds), for a key that tells all bits apart."""
    if isinstance(value, (float, np.floating)):
        return float(value).hex()
    if isinstance(value, (tuple, list, np.ndarray)):
        return tuple(_exact(item) for item in value)
    return value


def chunk_key(robot: str, space: SampleSpace, seed: int, task: str, indices: Sequence[int]) -> str:
    """The entry's name: every input of the samples ``indices`` of ``task``."""
    fields = tuple((field.name, _exact(getattr(space, field.name))) for field in dataclasses.fields(space))
    content = (
        "samples", task, int(seed), tuple(int(i) for i in indices), fields, _arm(robot),
        code_fingerprint(type(get_task(task)).__module__),
    )  # fmt: skip
    return hashlib.sha256(pickle.dumps(content, protocol=5)).hexdigest()


def read_chunk(
    folder: Path, key: str, task: str, indices: Sequence[int], limits: tuple[np.ndarray, np.ndarray]
) -> list[EvaluationSample] | None:
    """The cached samples of one chunk, or ``None`` where there is no entry or it is damaged (named on stderr).

    A sample read back must be the one asked for: the task and index of its place, θ₀ inside ``limits`` (lower,
    upper) and a reference its task reads."""
    path = folder / f"{key}.json"
    try:
        rows = read_entry(path, key)
        if rows is None:
            return None
        if not isinstance(rows, list) or len(rows) != len(indices):
            raise DamagedEntry(path, f"it holds {len(rows) if isinstance(rows, list) else 'no'} samples, not "
                                     f"{len(indices)}")  # fmt: skip
        return [_sample(path, row, task, int(index), limits) for row, index in zip(rows, indices, strict=True)]
    except DamagedEntry as problem:
        WARNINGS.damaged([problem])
        return None


def _sample(path: Path, row: Any, task: str, index: int, limits: tuple[np.ndarray, np.ndarray]) -> EvaluationSample:
    if not isinstance(row, dict) or not all(isinstance(cell, str) for cell in row.values()):
        raise DamagedEntry(path, "a sample is not a row of cells")
    reader = RowReader(path, index, 0, row)
    try:
        if reader.text("task") != task or reader.text("sample") != str(index):
            raise DamagedEntry(path, f"it holds another sample than {task} {index}")
        lower, upper = limits
        q0 = reader.numbers([f"q0_{j}" for j in range(len(lower))])
        if not np.all((lower <= q0) & (q0 <= upper)):
            raise DamagedEntry(path, f"sample {index}'s θ₀ is outside the joint limits")
        return EvaluationSample(task, index, q0, get_task(task).read_csv_reference(reader))
    except (ValueError, KeyError, TypeError) as exc:  # SampleFileError is a ValueError
        raise DamagedEntry(path, f"sample {index} does not read ({exc})") from None


def write_chunk(folder: Path, key: str, samples: Sequence[EvaluationSample], n_joints: int) -> None:
    """Store one chunk's samples atomically. A folder that cannot be written costs later runs a draw, not this one: it
    is named once on stderr and the run goes on."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        write_entry(folder / f"{key}.json", key, [sample_row(sample, n_joints) for sample in samples])
    except OSError as exc:
        WARNINGS.unwritable(folder, exc)


__all__ = [
    "DISTRIBUTIONS", "ROOTS", "SWITCH_ENV", "WARNINGS",
    "cache_enabled", "cache_folder", "cacheable", "chunk_key", "code_fingerprint", "read_chunk", "write_chunk",
]  # fmt: skip
