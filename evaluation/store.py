"""The output directory: what is written as results arrive, and what ``--resume`` reads back.

Layout of ``--out DIR``::

    .lock                 held while a run uses the folder (a second run on it is refused)
    run.json              the inputs that determine the results (checked by --resume): options,
                          hashes of the samples file and of the controllers' model files
    samples.csv           the sample set, in the documented CSV format
    calibration.json      effort matching: every knob value tried and its effort; or the knobs the run
                          read from the calibration cache or the shipped file (what --resume reads)
    parts/                one Parquet file per completed job (written atomically)
    trajectories/TASK/CONTROLLER/sample_NNNNN.parquet   with --save-trajectories
    results.csv, results.parquet, summary.csv, summary.md, cost_boxplot.png

A job's part file is written only after its trajectories, by renaming a finished temporary
file, so a part on disk means the job is complete. Each part carries the run's id (a hash of
``run.json``) and its sample ids in its Parquet metadata, and the SHA-256 of its bytes beside it
(``PART.sha256``, written before the part is renamed into place). A resumed run skips every job whose
part exists and is intact, recomputes the others (a part whose bytes no longer match its checksum, or
that has none, is moved aside as ``PART.corrupt`` and its job run again, with a line on stderr), and
refuses a part of another run or of other samples: no completed sample is lost, counted twice, mixed in
from elsewhere or read from a damaged file. Reading a part checks it again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]

from snac_gym.evaluation.samples import SampleFileError

from snac_gym.common.errors import RunDirectoryError
from snac_gym.common.outputs import (
    OutputFolderError,
    read_json_object,
    usable_out_folder,
    write_text_whole,
    written_whole,
)
from snac_gym.rollout import write_log

#: The table of every row, written once all of a run's rows are in: a run whose folder holds it is finished.
RESULTS_FILE = "results.parquet"

#: Parquet schema-metadata keys of a part file: the run it belongs to and the sample ids it holds.
_PART_RUN_KEY, _PART_SAMPLES_KEY = b"snac_gym.run", b"snac_gym.samples"


def _ids_text(ids: str) -> str:
    """A part's sample ids (JSON) in a few words: ``samples 0-3`` or ``4 samples from 12``."""
    try:
        values = [int(i) for i in json.loads(ids)]
    except (ValueError, TypeError):
        return "unreadable sample ids"
    if not values:
        return "no samples"
    if values == list(range(values[0], values[0] + len(values))):
        return f"sample {values[0]}" if len(values) == 1 else f"samples {values[0]}-{values[-1]}"
    return f"{len(values)} samples from {min(values)} to {max(values)}"


def _stable_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=str)


def settings_key(kwargs: dict[str, Any], steps: int, engine: str, sample_set: str = "") -> str:
    """Short hash of what decides a job's output besides its samples, and of the pass's sample set where it is not the
    run's own (``sample_set``, e.g. the effort set of a match, whose chunks hold other samples than the run's)."""
    settings: dict[str, Any] = {"kwargs": kwargs, "steps": steps, "engine": engine}
    if sample_set:  # the run's own passes keep the names they always had
        settings["sample_set"] = sample_set
    return hashlib.sha1(_stable_json(settings).encode()).hexdigest()[:12]


def run_id(manifest: dict[str, Any]) -> str:
    """The identity of a run: a hash of its manifest (every input that shapes the results)."""
    return hashlib.sha256(_stable_json(manifest).encode()).hexdigest()[:16]


def file_sha1(path: Path, what: str) -> str:
    """SHA-1 of a file's bytes (the samples file and the controllers' input files in ``run.json``).

    Raises:
        SampleFileError: If it cannot be read (one line naming ``what`` and the file).
    """
    digest = hashlib.sha1()
    try:
        with Path(path).open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    return digest.hexdigest()


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checksum_path(part: Path) -> Path:
    """Where the SHA-256 of ``part`` is kept."""
    return part.with_name(part.name + ".sha256")


def part_is_intact(part: Path) -> bool:
    """Whether ``part``'s bytes still have the SHA-256 written beside them when it was stored."""
    try:
        return checksum_path(part).read_text().strip() == _sha256(part)
    except OSError:
        return False


def _tmp_path(path: Path) -> Path:
    # Unique per process and thread: two writers never share a temporary file.
    return path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")


def _usable_folder(root: Path) -> None:
    """Refuse an ``--out`` that is a file or cannot be written, with one line saying which."""
    try:
        usable_out_folder(root)
    except OutputFolderError as exc:
        raise RunDirectoryError(str(exc)) from None


class _FolderLock:
    """An exclusive lock on ``root/.lock`` held while a run uses the folder (POSIX ``flock``).

    The kernel drops the lock with the last descriptor of the file, so a killed run never leaves
    a stale lock behind.
    """

    def __init__(self, root: Path) -> None:
        self.path = root / ".lock"
        self.made = False  # whether this lock made the file
        try:
            try:
                self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
                self.made = True
            except FileExistsError:
                self._fd = os.open(self.path, os.O_RDWR)
        except OSError as exc:
            raise RunDirectoryError(f"cannot write to the output folder {root}: {exc.strerror or exc}") from None
        if fcntl is None:  # pragma: no cover - not POSIX: no lock, as before
            return
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(self._fd, 64).decode(errors="replace").strip() or "another process"
            os.close(self._fd)
            self._fd = None
            raise RunDirectoryError(
                f"{root} is in use by another run (pid {holder}); wait for it to end or choose another --out"
            ) from None
        os.ftruncate(self._fd, 0)
        os.write(self._fd, str(os.getpid()).encode())

    def release(self, remove: bool = False) -> None:
        """Unlock; with ``remove``, first delete the file if this lock made it (while it is still held, so that no
        other run locks the file being deleted)."""
        if self._fd is not None:
            if remove and self.made:
                self.path.unlink(missing_ok=True)
            os.close(self._fd)
            self._fd = None


class RunStore:
    """Reads and writes one evaluation's output directory.

    The folder is locked from construction to :meth:`close` (a second run on it is refused),
    and every part file carries the run's id and its sample ids, so a resume never mixes in
    parts of another run.

    Args:
        root: The ``--out`` directory.
        manifest: The inputs that determine the results (written to ``run.json`` by :meth:`begin`).
        resume: Continue the run in ``root``; otherwise ``root`` must not hold a run yet.

    Raises:
        RunDirectoryError: If ``root`` is a file, cannot be written or is in use by another run;
            if it holds a run and ``resume`` is false, if ``resume`` is true and it holds none,
            if its ``run.json`` is unreadable, or if the stored inputs differ from ``manifest``.
    """

    def __init__(self, root: str | Path, manifest: dict[str, Any], resume: bool) -> None:
        self.root = Path(root)
        self.parts = self.root / "parts"
        self.trajectories = self.root / "trajectories"
        self.manifest = json.loads(_stable_json(manifest))
        self.run_id = run_id(self.manifest)
        self._made_root = not self.root.exists()
        _usable_folder(self.root)
        self._lock = _FolderLock(self.root)
        try:
            self._check_manifest(resume)
            self._calibration_path = self.root / "calibration.json"
            self._calibration_lock = threading.Lock()
            self.calibration: dict[str, Any] = self._read_calibration()
        except BaseException:
            self.close()
            raise

    def _check_manifest(self, resume: bool) -> None:
        manifest_path = self.root / "run.json"
        if not manifest_path.exists():
            if resume:
                raise RunDirectoryError(f"--resume: {self.root} holds no run to resume (no run.json)")
            return
        stored = read_json_object(manifest_path)
        if isinstance(stored, str):
            if not resume:
                raise RunDirectoryError(
                    f"{self.root} already holds a run (its run.json unreadable); choose another --out"
                )
            raise RunDirectoryError(
                f"--resume: {manifest_path} is unreadable ({stored}); "
                "it cannot be resumed, start it again in another --out"
            )
        normalised = self.manifest
        differing = sorted(k for k in set(stored) | set(normalised) if stored.get(k) != normalised.get(k))
        if not resume:
            # Running the same command again is the usual way here (to see it cached, or after a stop): say which of
            # the three cases it is, so that --resume is suggested only where it would be taken.
            if differing:
                raise RunDirectoryError(
                    f"{self.root} already holds another run (its inputs differ: {', '.join(differing)}); "
                    "choose another --out"
                )
            if (self.root / RESULTS_FILE).exists():
                raise RunDirectoryError(
                    f"{self.root} already holds this run, finished; pass --resume to write its reports again from "
                    "its rows, or choose another --out to run it again"
                )
            raise RunDirectoryError(
                f"{self.root} already holds this run, unfinished; pass --resume to continue it or choose another --out"
            )
        if differing:
            details = "; ".join(f"{k}: stored {stored.get(k)!r}, now {normalised.get(k)!r}" for k in differing)
            raise RunDirectoryError(f"--resume: the inputs differ from the run in {self.root}: {details}")

    def _read_calibration(self) -> dict[str, Any]:
        if not self._calibration_path.exists():
            return {}
        try:
            record = json.loads(self._calibration_path.read_text())
        except (ValueError, OSError) as exc:
            raise RunDirectoryError(f"--resume: {self._calibration_path} is unreadable: {exc}") from None
        if not isinstance(record, dict) or record.get("run") != self.run_id:
            raise RunDirectoryError(
                f"--resume: {self._calibration_path} does not belong to the run in {self.root} "
                f"(run id {record.get('run') if isinstance(record, dict) else None!r}, expected {self.run_id!r}); "
                "remove it to search the knobs again"
            )
        return {k: v for k, v in record.items() if k != "run"}

    def begin(self) -> None:
        """Write ``run.json`` (once the sample set is known, so that a run that fails before has none)."""
        self.parts.mkdir(parents=True, exist_ok=True)
        manifest_path = self.root / "run.json"
        if not manifest_path.exists():
            self._write_text(manifest_path, json.dumps(self.manifest, indent=2, sort_keys=True))

    def close(self) -> None:
        """Release the folder lock. A run that ends before :meth:`begin` (refused, failed or interrupted while its
        samples were drawn) leaves no lock file, nor the folder if it made it and it is empty: nothing was written."""
        begun = (self.root / "run.json").exists()
        self._lock.release(remove=not begun)
        if not begun and self._made_root:
            with contextlib.suppress(OSError):  # not empty: kept
                self.root.rmdir()

    def __enter__(self) -> RunStore:  # noqa: PYI034 - Self needs Python 3.11
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def _write_text(path: Path, text: str) -> None:
        write_text_whole(path, text)

    # -- parts --------------------------------------------------------------------------------
    def part_path(self, task: str, controller: str, key: str, chunk: int) -> Path:
        """Where the part of chunk ``chunk`` of a pass is stored."""
        return self.parts / f"{task}__{controller}__{key}__{chunk:05d}.parquet"

    def has_part(self, path: Path, sample_ids: Sequence[int]) -> bool:
        """Whether the part at ``path`` is done; a part of another run or of other samples is refused.

        Raises:
            RunDirectoryError: If the file exists but was not written by this run for ``sample_ids``.
        """
        if not path.is_file():
            return False
        try:
            metadata: dict[bytes, bytes] | None = pq.read_schema(path).metadata or {}
        except (OSError, ValueError, pa.ArrowException) as exc:
            metadata, unreadable = None, exc
        if metadata is not None:  # a part another run or other samples wrote is refused, not redone
            stored_run = metadata.get(_PART_RUN_KEY, b"").decode(errors="replace")
            stored_ids = metadata.get(_PART_SAMPLES_KEY, b"").decode(errors="replace")
            expected_ids = json.dumps([int(i) for i in sample_ids])
            if stored_run != self.run_id:
                raise RunDirectoryError(
                    f"--resume: the part file {path} belongs to another run (run {stored_run or 'unknown'!r}, "
                    f"this run {self.run_id!r}); remove it to recompute that job"
                )
            if stored_ids != expected_ids:
                raise RunDirectoryError(
                    f"--resume: the part file {path} belongs to other samples (it holds {_ids_text(stored_ids)}, "
                    f"this job runs {_ids_text(expected_ids)}); remove it to recompute that job"
                )
        if not part_is_intact(path):  # damaged (or stored before checksums): never read, run again
            aside = path.with_name(path.name + ".corrupt")
            os.replace(path, aside)
            sys.stderr.write(
                f"--resume: the part file {path.name} does not match its SHA-256 (or has none); "
                f"moved to {aside.name}, its job runs again\n"
            )
            return False
        if metadata is None:
            raise RunDirectoryError(f"--resume: the part file {path} is unreadable ({unreadable}); remove it")
        return True

    def write_part(self, path: Path, rows: pd.DataFrame) -> None:
        """Store a completed job's rows, stamped with the run id and sample ids (atomically: a part on disk is
        complete)."""
        table = pa.Table.from_pandas(rows, preserve_index=False)
        stamp = {
            _PART_RUN_KEY: self.run_id.encode(),
            _PART_SAMPLES_KEY: json.dumps([int(i) for i in rows["sample"]]).encode(),
        }
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **stamp})
        with written_whole(path) as tmp:
            pq.write_table(table, tmp)
            self._write_text(checksum_path(path), _sha256(tmp) + "\n")  # before the part: a part on disk has its sum

    def read_part(self, path: Path) -> pd.DataFrame:
        """A stored part's rows, after its bytes are checked against their SHA-256.

        Raises:
            RunDirectoryError: If the part changed after it was written.
        """
        if not part_is_intact(path):
            raise RunDirectoryError(
                f"the part file {path} changed after it was written (its SHA-256 does not match "
                f"{checksum_path(path).name}); "
                "remove it and run again with --resume to recompute that job"
            )
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
            stamped = {"run": self.run_id, **self.calibration}
            self._write_text(self._calibration_path, json.dumps(stamped, indent=2, sort_keys=True))

    def write_text(self, name: str, text: str) -> Path:
        path = self.root / name
        self._write_text(path, text)
        return path
