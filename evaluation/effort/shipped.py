"""The default controllers' matched knobs, shipped with the package: a first run at the default settings
matches no effort, as a second run finds them in the calibration cache.

Equal effort at the evaluator's defaults (Table I's main command: the paper's effort reference ``snac``, the
default seed, sample space, 1000-sample effort set, horizons, cost and statistic) is a fixed computation, like
the shipped PPO weights are a fixed training run. ``python tools/ship_calibration.py`` runs it and writes
:func:`shipped_file`: each (task, controller)'s record with the whole identity it was matched for
(:func:`~snac_gym.evaluation.effort.cache.calibration_identity`) less the code fingerprint, which every edit of
the package changes. A run uses a shipped record only where its own identity, less that fingerprint, is the
same (the same controller settings and files, the same effort set and options, the same effort reference);
otherwise it matches, or reads the calibration cache, as before. ``--recalibrate`` matches anew.

What stands in for the fingerprint is a test: ``tests/evaluation/effort/test_shipped.py`` recomputes every shipped
knob search with the current code, on the same effort set, and fails when a knob or its effort moves by a bit.
"""

from __future__ import annotations

import dataclasses
import json
from importlib.metadata import version
from pathlib import Path
from typing import Any

from snac_gym.evaluation.effort.matching import EffortRecord

import snac_gym
from snac_gym.common.machine import cpu_target

#: How a summary names the knobs' origin.
SHIPPED_ORIGIN = "the knobs shipped with snac-gym (tools/ship_calibration.py, checked by the test suite)"


#: The libraries whose numerics a knob's last bits depend on, besides the code.
NUMERICS = ("numpy", "scipy", "pin", "numba")


def numerics() -> dict[str, str]:
    """What a knob's last bits depend on besides the code: :data:`NUMERICS`' versions, and the CPU that numba
    compiles the kernels for (``cpu``), as its vector width and fused multiply-adds round differently."""
    return {**{name: version(name) for name in NUMERICS}, "cpu": cpu_target()}


def shipped_file() -> Path:
    """The shipped knobs: ``data/calibration/default_knobs.json`` of the installed ``snac_gym`` package."""
    return Path(snac_gym.__file__).resolve().parent / "data" / "calibration" / "default_knobs.json"


def without_code(identity: dict[str, Any]) -> dict[str, Any]:
    """``identity`` as JSON would store it, less its ``code`` fingerprint."""
    plain = json.loads(json.dumps(identity, default=str, sort_keys=True))
    plain.pop("code", None)
    return plain


def read_shipped(
    identities: dict[tuple[str, str], dict[str, Any]], path: Path | None = None
) -> tuple[dict[tuple[str, str], EffortRecord], dict[str, Any]] | None:
    """The shipped records of every (task, controller) of ``identities`` and the file's stamp, or ``None`` unless
    every one of them is shipped for the same identity (less the code)."""
    path = shipped_file() if path is None else path
    try:
        shipped = json.loads(path.read_text())
        entries = {(e["record"]["task"], e["record"]["controller"]): e for e in shipped["entries"]}
    except (OSError, ValueError, KeyError, TypeError):
        return None
    records: dict[tuple[str, str], EffortRecord] = {}
    for key, identity in identities.items():
        entry = entries.get(key)
        if entry is None or entry.get("identity") != without_code(identity):
            return None
        try:
            records[key] = EffortRecord(**entry["record"])
        except TypeError:
            return None
    return records, {"origin": SHIPPED_ORIGIN, "at": shipped.get("made_at", "")}


def write_shipped(
    path: Path,
    identities: dict[tuple[str, str], dict[str, Any]],
    records: dict[tuple[str, str], EffortRecord],
    searches: dict[str, Any],
    stamp: dict[str, Any],
) -> Path:
    """Write the shipped file: every record with its identity less the code, the knob searches that found them
    (from the calibrating run's ``calibration.json``) and ``stamp`` (the command, versions, time)."""
    entries = [
        {"identity": without_code(identities[key]), "record": {**dataclasses.asdict(records[key]), "calibrated_by": ""}}
        for key in sorted(identities)
    ]
    payload = {**stamp, "entries": entries, "searches": searches}
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".tmp")
    partial.write_text(json.dumps(payload, indent=1, sort_keys=True, default=str) + "\n")
    partial.replace(path)
    return path


__all__ = ["SHIPPED_ORIGIN", "read_shipped", "shipped_file", "without_code", "write_shipped"]
