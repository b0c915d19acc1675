"""The output directory: what is written as results arrive, and what ``--resume`` reads back.

Layout of ``--out DIR``::

    run.json              the options that determine the results (checked by --resume)
    samples.csv           the sample set, in the documented CSV format
    calibration.json      effort matching: every knob value tried and its effort
    parts/                one Parquet file per completed job (written atomically)
    trajectories/TASK/CONTROLLER/sample_NNNNN.parquet   with --save-trajectories
    results.csv, results.parquet, summary.csv, summary.md, cost_boxplot.png

A job's part file is written only after its trajectories, by renaming a finished temporary
file, so a part on disk means the job is complete. A resumed run skips every job whose part
exists and recomputes the others: no completed sample is lost or counted twice.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from pathlib import Path
from typing import Any

import pandas as pd

from snac_gym.rollout import write_log


class RunDirectoryError(RuntimeError):
    """The output directory holds another run, or --resume finds nothing to resume."""


def _stable_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=str)


def settings_key(kwargs: dict[str, Any], steps: int, backend: str) -> str:
    """Short hash of what decides a job's output besides its samples."""
    return hashlib.sha1(_stable_json({"kwargs": kwargs, "steps": steps, "backend": backend}).encode()).hexdigest()[:12]


class RunStore:
    """Reads and writes one evaluation's output directory.

    Args:
        root: The ``--out`` directory.
        manifest: The options that determine the results (written to ``run.json``).
        resume: Continue the run in ``root``; otherwise ``root`` must not hold a run yet.

    Raises:
        RunDirectoryError: If ``root`` holds a run and ``resume`` is false, if ``resume`` is
            true and ``root`` holds none, or if the stored options differ from ``manifest``.
    """

    def __init__(self, root: str | Path, manifest: dict[str, Any], resume: bool) -> None:
        self.root = Path(root)
        self.parts = self.root / "parts"
        self.trajectories = self.root / "trajectories"
        manifest_path = self.root / "run.json"
        if manifest_path.exists():
            if not resume:
                raise RunDirectoryError(
                    f"{self.root} already holds a run; pass --resume to continue it or choose another --out"
                )
            stored = json.loads(manifest_path.read_text())
            normalised = json.loads(_stable_json(manifest))
            differing = sorted(k for k in set(stored) | set(normalised) if stored.get(k) != normalised.get(k))
            if differing:
                details = "; ".join(f"{k}: stored {stored.get(k)!r}, now {normalised.get(k)!r}" for k in differing)
                raise RunDirectoryError(f"--resume: the options differ from the run in {self.root}: {details}")
        elif resume:
            raise RunDirectoryError(f"--resume: {self.root} holds no run to resume (no run.json)")
        self.parts.mkdir(parents=True, exist_ok=True)
        if not manifest_path.exists():
            self._write_text(manifest_path, json.dumps(json.loads(_stable_json(manifest)), indent=2, sort_keys=True))
        self._calibration_path = self.root / "calibration.json"
        self._calibration_lock = threading.Lock()
        self.calibration: dict[str, Any] = (
            json.loads(self._calibration_path.read_text()) if self._calibration_path.exists() else {}
        )

    @staticmethod
    def _write_text(path: Path, text: str) -> None:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text)
        os.replace(tmp, path)

    # -- parts --------------------------------------------------------------------------------
    def part_path(self, task: str, controller: str, key: str, chunk: int) -> Path:
        """Where the part of chunk ``chunk`` of a pass is stored."""
        return self.parts / f"{task}__{controller}__{key}__{chunk:05d}.parquet"

    def has_part(self, path: Path) -> bool:
        return path.is_file()

    def write_part(self, path: Path, rows: pd.DataFrame) -> None:
        """Store a completed job's rows (atomically: a part on disk is complete)."""
        tmp = path.with_name(path.name + ".tmp")
        rows.to_parquet(tmp, index=False)
        os.replace(tmp, path)

    def read_part(self, path: Path) -> pd.DataFrame:
        return pd.read_parquet(path)

    # -- trajectories -----------------------------------------------------------------------------
    def trajectory_path(self, task: str, controller: str, sample: int) -> Path:
        return self.trajectories / task / controller / f"sample_{sample:05d}.parquet"

    def write_trajectory(self, log: pd.DataFrame, task: str, controller: str, sample: int) -> Path:
        """Write one rollout's per-step log (the demo's format, :func:`snac_gym.rollout.write_log`)."""
        path = self.trajectory_path(task, controller, sample)
        path.parent.mkdir(parents=True, exist_ok=True)
        written = write_log(log, self.trajectories / ".incomplete" / f"{task}__{controller}__{path.name}")[0]
        os.replace(written, path)  # a log at its final path is complete
        return path

    # -- calibration record ---------------------------------------------------------------------
    def save_calibration(self, key: str, record: Any) -> None:
        """Store one calibration step's record under ``key`` (kept across --resume)."""
        with self._calibration_lock:  # concurrent effort matches save their records
            self.calibration[key] = json.loads(_stable_json(record))
            self._write_text(self._calibration_path, json.dumps(self.calibration, indent=2, sort_keys=True))

    def write_text(self, name: str, text: str) -> Path:
        path = self.root / name
        self._write_text(path, text)
        return path
