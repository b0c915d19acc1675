"""Matched effort knobs, cached on disk across runs: a small question asked after one full calibration
answers in seconds.

A controller's matched knob depends on the arm, the task, its horizon and Δt, the engine (always the kinematic
model, where every run matches, one in a physics engine included), the cost, the effort statistic, tolerance and
target, the **effort set** (the samples it is matched on: the seed, the
sample space and the set's size, or the samples file's content), the controller's settings and files,
the effort reference's settings and files, and the code. It does not depend on how many of the effort
set's samples a run reports: ``--samples 50`` is matched on the first 1000 samples, like ``--samples
1000``. Each (task, controller) is one JSON file named by the SHA-256 of all of those inputs; the code
enters as the SHA-256 of every source file of the package and of the shipped PPO policies, with the
versions of NumPy, SciPy, Pinocchio and Numba, so that a changed controller, rollout or statistic never
reuses a stale knob.

A run reuses the cache only when every (task, controller) it matches is there (a partial hit re-runs the
whole match, which a new target would change anyway). It then runs each controller once on the samples
it reports, at the cached knob, and its summary names the run that calibrated it. ``--recalibrate``
matches anew and overwrites the entries. The folder is ``$SNAC_GYM_CACHE_DIR/calibration`` (default
``~/.cache/snac-gym/calibration``, or under ``$XDG_CACHE_HOME``); ``SNAC_GYM_CALIBRATION_CACHE=0`` turns it off
(the test suite does, so that no test compares a knob with itself).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import snac_gym.baselines
from snac_gym.evaluation.cache_entry import CacheWarnings, DamagedEntry, read_entry, write_entry
from snac_gym.evaluation.effort.matching import EffortRecord
from snac_gym.evaluation.reference.cache import add_versions, cache_root
from snac_gym.evaluation.run_config import ControllerSpec, EvaluationConfig

import snac_gym
from snac_gym.common.cache_dir import switched_on

#: Environment variable that turns the cache off (``0``, ``off``, ``false`` or ``no``) whatever the options say.
SWITCH_ENV = "SNAC_GYM_CALIBRATION_CACHE"
#: Distributions whose version is part of the key (their numerics shape the rollouts).
DISTRIBUTIONS = ("numpy", "scipy", "pin", "example-robot-data", "numba", "stable-baselines3", "torch")
#: Files besides the sources that controllers read from the package (the shipped PPO policies).
DATA_PATTERNS = ("*.py", "*.npz", "*.json")


def cache_enabled() -> bool:
    """Whether :data:`SWITCH_ENV` leaves the cache on (it is, unless set to ``0``, ``off``, ``false`` or ``no``)."""
    return switched_on(SWITCH_ENV)


def calibration_folder() -> Path:
    """The matched knobs: ``calibration`` under :func:`~snac_gym.evaluation.reference.cache.cache_root`."""
    return cache_root() / "calibration"


def package_folders() -> tuple[tuple[str, Path], ...]:
    """The folders the installed package reads its code and shipped files from: ``snac_gym`` and the folders
    its ``baselines`` and ``evaluation`` install from."""
    evaluation = Path(__file__).resolve().parents[1]  # this package's own folder (its __init__ imports the runner)
    return (
        ("snac_gym", Path(snac_gym.__file__).parent),
        ("snac_gym.baselines", Path(snac_gym.baselines.__file__).parent),
        ("snac_gym.evaluation", evaluation),
    )


#: Sub-folders no knob depends on: the command line (its options are in the key), the real arm, the reports.
UNUSED_BY_MATCHING = {("snac_gym", "apps"), ("snac_gym", "real"), ("snac_gym.evaluation", "reports")}


def folders_fingerprint(folders: Sequence[tuple[str, Path]]) -> str:
    """SHA-256 of every file of :data:`DATA_PATTERNS` under each named folder (but :data:`UNUSED_BY_MATCHING`):
    its path and its content."""
    digest = hashlib.sha256()
    for name, root in folders:
        files = sorted(
            f
            for f in {f for pattern in DATA_PATTERNS for f in root.rglob(pattern)}
            if "__pycache__" not in f.parts and (name, f.relative_to(root).parts[0]) not in UNUSED_BY_MATCHING
        )
        for path in files:
            digest.update(f"{name}/{path.relative_to(root).as_posix()}".encode())
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of :func:`folders_fingerprint` of the :func:`package_folders` and of the versions of
    :data:`DISTRIBUTIONS`."""
    digest = hashlib.sha256(folders_fingerprint(package_folders()).encode())
    add_versions(digest, DISTRIBUTIONS)
    return digest.hexdigest()


def _controller(spec: ControllerSpec) -> dict[str, Any]:
    return {
        "name": spec.name,
        "kwargs": spec.kwargs,
        "knob": spec.knob,
        "knob_value": spec.knob_value,
        "files": dict(spec.inputs),
    }


def calibration_identity(
    config: EvaluationConfig,
    manifest: dict[str, Any],
    task: str,
    spec: ControllerSpec,
    reference: ControllerSpec | None,
) -> dict[str, Any]:
    """Everything the matched knob of ``spec`` on ``task`` depends on (the module docstring), as plain values.

    ``manifest`` is the run's :meth:`~snac_gym.evaluation.run_config.EvaluationConfig.manifest`; ``reference``
    the controller whose effort is the target (``None`` with an ``effort_target``).
    """
    effort_set = (
        {"samples_file_sha1": manifest["samples_file_sha1"]}
        if config.samples_file is not None
        else {"seed": config.seed, "space": manifest["space"], "size": max(config.samples, config.effort_samples)}
    )
    shared = (
        "robot",
        "dt",
        "engine",
        "effort_statistic",
        "effort_target",
        "effort_tolerance",
        "calibration_samples",
        "cost",
        "udot_start",
        "q_scale",
        "use_batch",
        "chunk_size",
        "reference_limits",
    )
    return {
        **{name: manifest[name] for name in shared},
        "model_error": manifest.get("model_error"),
        "task": task,
        "steps": config.steps(task),
        "effort_set": effort_set,
        "controller": _controller(spec),
        "effort_reference": None if reference is None else _controller(reference),
        "code": code_fingerprint(),
    }


def _key(identity: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()


#: The calibration cache's warnings: a damaged entry, an unwritable folder (one line each, on stderr).
WARNINGS = CacheWarnings("the calibration cache", f"{SWITCH_ENV}=0 turns it off, or set SNAC_GYM_CACHE_DIR")
#: The roles a record can have.
ROLES = ("reference", "matched", "unmatched", "fixed")


def check_record(record: EffortRecord, identity: dict[str, Any]) -> None:
    """Check a record read back as a fresh one holds: the task and controller of its identity, a known role, a
    finite effort, a positive finite knob where the controller has one (its own value where it is the effort
    reference), and a matched effort within the identity's tolerance of its target.

    Raises:
        ValueError: Naming the first field that does not hold.
    """
    controller = identity["controller"]
    if (record.task, record.controller) != (identity["task"], controller["name"]):
        raise ValueError(f"it is the record of {record.task}/{record.controller}")
    if record.role not in ROLES:
        raise ValueError(f"role {record.role!r} is not one of {', '.join(ROLES)}")
    if not (isinstance(record.effort, (int, float)) and math.isfinite(record.effort) and record.effort >= 0):
        raise ValueError(f"effort {record.effort!r} is not finite and non-negative")
    _check_knob(record, controller)
    if record.role == "matched":
        target = record.target
        if not (isinstance(target, (int, float)) and math.isfinite(target) and target > 0):
            raise ValueError(f"target {target!r} is not positive and finite")
        if abs(record.effort - target) > identity["effort_tolerance"] * target * (1 + 1e-9):
            raise ValueError(f"a matched effort {record.effort!r} is not within the tolerance of its target {target!r}")
    if not (isinstance(record.passes, int) and record.passes >= 1):
        raise ValueError(f"passes {record.passes!r} is not a whole number ≥ 1")


def _check_knob(record: EffortRecord, controller: dict[str, Any]) -> None:
    if record.knob != controller["knob"]:
        raise ValueError(f"knob {record.knob!r} is not the controller's {controller['knob']!r}")
    if record.knob is None:
        return
    value = record.knob_value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"knob_value {value!r} is not positive and finite")
    if record.role == "reference" and value != controller["knob_value"]:
        raise ValueError(f"the effort reference's knob_value {value!r} is not its own {controller['knob_value']!r}")


def read_records(
    folder: Path, identities: dict[tuple[str, str], dict[str, Any]]
) -> tuple[dict[tuple[str, str], EffortRecord], dict[str, Any]] | None:
    """The cached records of every (task, controller) of ``identities`` and the calibrating run's stamp, or
    ``None`` unless all of them are cached. An entry is used only if it holds its identity, matches its checksum
    and its record holds (:func:`check_record`); a damaged one is named on stderr and counts as missing (the run
    matches anew and overwrites it)."""
    if folder.exists() and not folder.is_dir():  # nothing cached there; the run says so where it stores the knobs
        return None
    records: dict[tuple[str, str], EffortRecord] = {}
    stamp: dict[str, Any] = {}
    for key, identity in identities.items():
        path = folder / f"{_key(identity)}.json"
        try:
            entry = read_entry(path, identity)
            if entry is None:
                return None
            try:
                record = EffortRecord(**entry["record"])
                check_record(record, json.loads(json.dumps(identity, default=str)))
                stamp = dict(entry["calibrated_by"])
            except (ValueError, KeyError, TypeError) as exc:
                raise DamagedEntry(path, f"its record does not hold ({exc})") from None
        except DamagedEntry as problem:
            WARNINGS.damaged([problem])
            return None
        records[key] = record
    return records, stamp


def write_records(
    folder: Path,
    identities: dict[tuple[str, str], dict[str, Any]],
    records: dict[tuple[str, str], EffortRecord],
    run: str,
) -> None:
    """Store each record of ``records`` under its identity, stamped with ``run`` (the output folder) and the time,
    with its identity and checksum (:mod:`snac_gym.evaluation.cache_entry`), atomically. A folder that cannot be
    written is named once on stderr, with how to turn the cache off, and the run goes on."""
    stamp = {"run": run, "at": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for key, identity in identities.items():
            if key not in records:
                continue
            payload = {"record": dataclasses.asdict(records[key]), "calibrated_by": stamp}
            write_entry(folder / f"{_key(identity)}.json", json.loads(json.dumps(identity, default=str)), payload)
    except OSError as exc:
        WARNINGS.unwritable(folder, exc)
