"""The optimal reference's rows, cached on disk by sample content.

The reference depends on a sample (θ₀ and its reference), the horizon, Δt, the cost convention, the
arm and its constraints, and on the code that computes it: never on the run's controllers. A row
computed once is therefore valid for every later run with the same inputs, whatever its seed, sample
id, sample count or workers. Each entry is one JSON file named by the SHA-256 of all of those inputs,
the code included (the source of every module the solve reads, and the versions of NumPy, SciPy and
Pinocchio), so that a changed solver, cost or kinematics never reuses a stale row.

The folder is ``$SNAC_GYM_CACHE_DIR/reference`` (default ``~/.cache/snac-gym/reference``, or under
``$XDG_CACHE_HOME``); ``--no-reference-cache`` solves every sample anew. JSON keeps every float bit for
bit (``repr``), NaN included, so a cached row equals the computed one exactly.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

#: Environment variable naming the cache's parent folder.
CACHE_ENV = "SNAC_GYM_CACHE_DIR"
#: The modules whose source the reference's rows depend on (its solver, starts, cost, model, metrics).
SOURCES = (
    "snac_gym.evaluation.reference.optimum",
    "snac_gym.trajopt",
    "snac_gym.kernels.trajopt",
    "snac_gym.kernels.chain",
    "snac_gym.kernels.small",
    "snac_gym.kernels.lqr",
    "snac_gym.kernels.relaxation",
    "snac_gym.model_error",
    "snac_gym.tasks.pose",
    "snac_gym.evaluation.execution.jobs",
    "snac_gym.cost",
    "snac_gym.kinematics",
    "snac_gym.metrics",
    "snac_gym.kernels.metrics",
    "snac_gym.joint_limits",
    "snac_gym.references",
    "snac_gym.rollout.kinematic",
    "snac_gym.rollout.episode",
    "snac_gym.optimality",
    "snac_gym.baselines.lqr",
    "snac_gym.baselines.dls",
    "snac_gym.baselines.joint_goal",
    "snac_gym.joint_goal",
    "snac_gym.baselines._common",
)
#: Distributions whose version is part of the key (their numerics shape the rows).
DISTRIBUTIONS = ("numpy", "scipy", "pin", "example-robot-data", "numba")


def cache_root() -> Path:
    """The parent of the project's caches: ``$SNAC_GYM_CACHE_DIR``, else ``$XDG_CACHE_HOME/snac-gym`` or
    ``~/.cache/snac-gym``."""
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "snac-gym"


def cache_folder() -> Path:
    """The reference's rows: ``reference`` under :func:`cache_root`."""
    return cache_root() / "reference"


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of the source of :data:`SOURCES` and the versions of :data:`DISTRIBUTIONS`."""
    digest = hashlib.sha256()
    for name in SOURCES:
        spec = importlib.util.find_spec(name)
        origin = None if spec is None else spec.origin
        digest.update(name.encode())
        digest.update(Path(origin).read_bytes() if origin else b"missing")
    add_versions(digest, DISTRIBUTIONS)
    return digest.hexdigest()


def add_versions(digest: Any, distributions: Sequence[str]) -> None:
    """Feed ``name==version`` of each installed distribution (``missing`` if not installed) to ``digest``."""
    for name in distributions:
        try:
            version = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            version = "missing"
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


def read_rows(folder: Path, keys: Sequence[str]) -> list[dict[str, Any] | None]:
    """Each key's cached row (without ``sample``), or ``None`` where there is none or it is unreadable."""
    rows: list[dict[str, Any] | None] = []
    for key in keys:
        try:
            rows.append(json.loads((folder / f"{key}.json").read_text()))
        except (OSError, ValueError):
            rows.append(None)
    return rows


def write_rows(folder: Path, keys: Sequence[str], rows: pd.DataFrame) -> None:
    """Store each row under its key, atomically (a file is whole or absent); a failure to write only
    costs a later solve, so it is not an error."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    for key, record in zip(keys, rows.drop(columns=["sample"]).to_dict("records"), strict=True):
        path, temporary = folder / f"{key}.json", folder / f".{key}.{os.getpid()}.tmp"
        try:
            temporary.write_text(json.dumps({name: _plain(value) for name, value in record.items()}))
            os.replace(temporary, path)
        except OSError:
            temporary.unlink(missing_ok=True)


def _plain(value: Any) -> Any:
    """A NumPy scalar as the Python value JSON writes exactly (floats by ``repr``)."""
    return value.item() if isinstance(value, np.generic) else value


__all__ = ["CACHE_ENV", "cache_folder", "code_fingerprint", "read_rows", "sample_key", "write_rows"]
