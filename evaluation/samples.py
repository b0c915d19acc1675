"""The evaluation's sample sets: random regulation and tracking samples, and their CSV form.

A *sample* is what one rollout starts from: a seed joint pose θ₀ and a reference (a fixed
target for ``reach``, a feasible ellipse for ``track``). Random samples come from the same
functions the envs' random resets use (:mod:`snac_gym.sampling`). Sample ``i`` of task ``T``
is drawn from its own generator, ``SeedSequence(seed, spawn_key=(task code, i))``, so it
does not depend on how many samples are drawn, in which order, or by which worker.

CSV format (one row per sample; see docs/evaluation.md)::

    task,sample,q0_0,...,q0_{m-1},target_0,target_1,target_2,
    centre_0,centre_1,centre_2,semi_axis_0,semi_axis_1,
    orientation_0,orientation_1,orientation_2,angular_speed,phase

* ``task``: ``reach`` or ``track``.
* ``sample``: a non-negative integer id, unique per task (optional column: rows are then
  numbered 0, 1, … per task in file order).
* ``q0_j``: seed joint angles, rad (all m required, inside the joint limits).
* ``reach`` rows: ``target_0..2`` (m, base frame) required; the ellipse columns empty.
* ``track`` rows: ``centre_0..2`` (m) and ``semi_axis_0..1`` (m, > 0) required;
  ``orientation_0..2`` (roll, pitch, yaw of the ellipse plane, rad; default 0),
  ``angular_speed`` (rad/s; default 0.075, the paper's) and ``phase`` (rad; default 0);
  the target columns empty.
* ``pose-reach`` and ``pose-track`` rows (the pose tasks, when a run names them,
  :mod:`snac_gym.tasks.pose`): the position reference in the columns of ``reach`` or ``track``
  plus ``rotvec_0..2``, the target orientation as a rotation vector log₃ R_d (rad, base frame);
  these columns exist only once the pose tasks are registered, so the position-only header is
  unchanged.

Every reference point (the target, or ``ellipse_points`` points around the ellipse) must be
reachable (a pose by the pose IK, with its orientation); a row that is not gives a :class:`SampleFileError` naming its
row and column.
"""

from __future__ import annotations

import csv
import functools
import math
import os
import stat
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from snac_gym.common.errors import SampleFileError
from snac_gym.common.outputs import written_whole
from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace, check_reachable, sample_seed_pose
from snac_gym.tasks import Sample, all_tasks, get_task, task_names

_POLICY_SEED_KEY = 1  # third spawn-key entry of a sample's policy seed


#: Largest sample id: ids are int64 columns of the results (and seed the policy resets).
MAX_SAMPLE_ID = np.iinfo(np.int64).max
#: Longest cell accepted, characters: a number needs a few dozen; a longer cell is not a sample.
MAX_CELL_CHARS = 1000


#: Largest samples file read, bytes: 64 MiB, about 250 000 rows (a row of Table I's file is about
#: 265 B), over 100x the paper's 2000 samples. A larger file, or one that never ends (/dev/zero),
#: would be hashed and parsed for as long as it lasts.
MAX_SAMPLES_FILE_BYTES = 64 * 2**20


def check_samples_file(path: str | Path) -> None:
    """Refuse, in one line, a samples file that is missing, not a regular file, or too large.

    ``stat`` only: opening a FIFO with no writer, or reading a device, would block or never end.

    Raises:
        SampleFileError: Naming the file and what is wrong with it.
    """
    try:
        status = os.stat(path)
    except FileNotFoundError:
        raise SampleFileError(f"{path}: no such samples file") from None
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read the samples file: {exc.strerror or exc}") from None
    if not stat.S_ISREG(status.st_mode):
        kind = "a folder" if stat.S_ISDIR(status.st_mode) else "a device, pipe or socket"
        raise SampleFileError(f"{path}: the samples file must be a regular CSV file, not {kind}")
    if status.st_size > MAX_SAMPLES_FILE_BYTES:
        raise SampleFileError(
            f"{path}: {status.st_size} bytes, above the samples file limit of {MAX_SAMPLES_FILE_BYTES} bytes "
            f"({MAX_SAMPLES_FILE_BYTES // 2**20} MiB); split it into several runs"
        )


#: One sample of a set (the rollout engine's :class:`snac_gym.tasks.Sample`).
EvaluationSample = Sample


def column_names(n_joints: int) -> list[str]:
    """The CSV header for a robot with ``n_joints`` joints: every registered task's columns, in order."""
    references = [column for task in all_tasks() for column in task.csv_columns]
    return ["task", "sample"] + [f"q0_{j}" for j in range(n_joints)] + list(dict.fromkeys(references))


def _sample_generator(seed: int, task: str, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(get_task(task).code, index)))


@functools.lru_cache(maxsize=1 << 16)  # asked for each sample of every job of a run's knob search
def policy_seed(seed: int, task: str, index: int) -> int:
    """The seed a policy is reset with for sample ``index`` of ``task`` (independent of N and workers)."""
    sequence = np.random.SeedSequence(seed, spawn_key=(get_task(task).code, index, _POLICY_SEED_KEY))
    return int(sequence.generate_state(1)[0])


def generate_sample(kinematics: Kinematics, space: SampleSpace, seed: int, task: str, index: int) -> EvaluationSample:
    """Sample ``index`` of ``task`` for ``seed``: the reference first, then the seed pose (as the envs do)."""
    spec = get_task(task)
    rng = _sample_generator(seed, task, index)
    reference = spec.sample(kinematics, rng, space)
    q0 = sample_seed_pose(kinematics, rng, space)
    return EvaluationSample(spec.name, index, q0, reference)


def generate_samples(
    kinematics: Kinematics, space: SampleSpace, seed: int, task: str, indices: Iterable[int]
) -> list[EvaluationSample]:
    """Samples ``indices`` of ``task`` (each from its own generator; see the module docstring)."""
    return [generate_sample(kinematics, space, seed, task, int(i)) for i in indices]


# -- CSV ---------------------------------------------------------------------------------------


def _format(value: float) -> str:
    return repr(float(value))  # shortest string that reads back to the same float


def sample_row(sample: EvaluationSample, n_joints: int) -> dict[str, str]:
    """The CSV cells of one sample."""
    row = {name: "" for name in column_names(n_joints)}
    row["task"] = sample.task
    row["sample"] = str(sample.index)
    for j, angle in enumerate(sample.q0):
        row[f"q0_{j}"] = _format(angle)
    for name, value in get_task(sample.task).csv_cells(sample.reference).items():
        row[name] = _format(value)
    return row


def write_samples_csv(samples: Sequence[EvaluationSample], path: str | Path, n_joints: int) -> Path:
    """Write ``samples`` in the documented CSV format (floats round-trip exactly)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with written_whole(path) as partial, partial.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=column_names(n_joints))
        writer.writeheader()
        for sample in samples:
            writer.writerow(sample_row(sample, n_joints))
    return path


class RowReader:
    """Typed access to one CSV row, with errors that name the file, row and column."""

    def __init__(self, path: Path, row_number: int, line: int, row: dict[str, str]) -> None:
        self.path, self.row_number, self.line, self.row = path, row_number, line, row

    def error(self, column: str, message: str) -> SampleFileError:
        return SampleFileError(f"{self.path}: row {self.row_number} (line {self.line}), column {column!r}: {message}")

    def text(self, column: str) -> str:
        return (self.row.get(column) or "").strip()

    def number(self, column: str, default: float | None = None) -> float:
        text = self.text(column)
        if not text:
            if default is not None:
                return default
            raise self.error(column, "a number is required here")
        try:
            value = float(text)
        except ValueError:
            raise self.error(column, f"{text!r} is not a number") from None
        if not math.isfinite(value):
            raise self.error(column, f"{text!r} is not a finite number")
        return value

    def numbers(self, columns: Sequence[str]) -> np.ndarray:
        return np.array([self.number(c) for c in columns])

    def require_empty(self, columns: Sequence[str], task: str) -> None:
        for column in columns:
            if self.text(column):
                raise self.error(column, f"must be empty on a {task!r} row (it belongs to the other task)")


def _parse_row(reader: RowReader, kinematics: Kinematics, space: SampleSpace, index: int) -> EvaluationSample:
    name = reader.text("task")
    if name not in task_names():
        raise reader.error("task", f"{name!r} is not one of {list(task_names())}")
    task = get_task(name)
    m = kinematics.n_joints
    q0 = reader.numbers([f"q0_{j}" for j in range(m)])
    for j in range(m):
        if not kinematics.lower_limits[j] <= q0[j] <= kinematics.upper_limits[j]:
            raise reader.error(
                f"q0_{j}",
                f"{q0[j]} rad is outside the joint limits [{kinematics.lower_limits[j]}, {kinematics.upper_limits[j]}]",
            )
    foreign = dict.fromkeys(c for other in all_tasks() for c in other.csv_columns if c not in task.csv_columns)
    reader.require_empty(list(foreign), name)
    reference = task.read_csv_reference(reader)
    try:
        # A pose task checks its poses itself (orientation included); the others are positions.
        check_pose = getattr(task, "check_reference", None)
        if check_pose is None:
            check_reachable(kinematics, reference.points(space.ellipse_points), f"{name} reference")
        else:
            check_pose(kinematics, reference, space.ellipse_points, f"{name} reference")
    except ValueError as exc:
        raise reader.error(task.csv_reference_span(), f"unreachable: {exc}") from None
    return EvaluationSample(name, index, q0, reference)


def read_samples_csv(
    path: str | Path, kinematics: Kinematics, space: SampleSpace | None = None
) -> dict[str, list[EvaluationSample]]:
    """Read a samples CSV (format in the module docstring), checking every row.

    Returns:
        The samples per task, in file order (tasks without rows map to an empty list).

    Raises:
        SampleFileError: On a missing, unreadable or non-UTF-8 file, a missing column, a
            malformed, oversized, out-of-limits or unreachable row, or a repeated sample id;
            the message names the file, the row, its line and the column.
    """
    path = Path(path)
    space = space if space is not None else SampleSpace.for_robot(kinematics)
    check_samples_file(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:  # -sig: a spreadsheet's byte-order mark
            reader = csv.DictReader(handle)
            try:
                return _read_rows(path, reader, kinematics, space)
            except csv.Error as exc:  # e.g. a cell beyond the csv module's field size limit
                raise SampleFileError(f"{path}: line {reader.line_num + 1}: not readable as CSV ({exc})") from None
    except UnicodeDecodeError as exc:
        raise SampleFileError(
            f"{path}: not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset {exc.start}); save it as UTF-8 CSV"
        ) from None
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read the samples file: {exc.strerror or exc}") from None


def _read_rows(
    path: Path, reader: csv.DictReader, kinematics: Kinematics, space: SampleSpace
) -> dict[str, list[EvaluationSample]]:
    header = [name.strip() for name in (reader.fieldnames or [])]
    reader.fieldnames = header
    required = ["task"] + [f"q0_{j}" for j in range(kinematics.n_joints)]
    missing = [name for name in required if name not in header]
    if missing:
        raise SampleFileError(
            f"{path}: header lacks the column(s) {missing}; expected columns {column_names(kinematics.n_joints)}"
        )
    known = set(column_names(kinematics.n_joints))
    unknown = [name for name in header if name not in known]
    if unknown:
        raise SampleFileError(
            f"{path}: unknown column(s) {unknown}; expected columns {column_names(kinematics.n_joints)}"
        )
    samples: dict[str, list[EvaluationSample]] = {task: [] for task in task_names()}
    seen: dict[str, set[int]] = {task: set() for task in task_names()}
    for row_number, row in enumerate(reader, start=1):
        # The reader skips blank lines, so the row count is not the line: ask the reader (the
        # last line of the record, which is also where a quoted cell spanning lines ends).
        line = reader.line_num
        if None in row:
            raise SampleFileError(f"{path}: row {row_number} (line {line}) has more cells than the header")
        row_reader = RowReader(path, row_number, line, row)
        too_long = [column for column, cell in row.items() if cell is not None and len(cell) > MAX_CELL_CHARS]
        if too_long:
            raise row_reader.error(
                too_long[0], f"a cell of {len(row[too_long[0]])} characters (at most {MAX_CELL_CHARS})"
            )
        task = row_reader.text("task")
        if "sample" in header:
            index = _sample_id(row_reader)
        else:
            index = len(samples.get(task, []))
        sample = _parse_row(row_reader, kinematics, space, index)
        if index in seen[task]:
            raise row_reader.error("sample", f"sample id {index} appears twice for task {task!r}")
        seen[task].add(index)
        samples[task].append(sample)
    return samples


def _sample_id(reader: RowReader) -> int:
    text = reader.text("sample")
    try:
        index = int(text)
    except ValueError:
        raise reader.error("sample", f"{text!r} is not a non-negative integer") from None
    if not 0 <= index <= MAX_SAMPLE_ID:
        raise reader.error("sample", f"{index} is outside [0, {MAX_SAMPLE_ID}] (ids are stored as 64-bit integers)")
    return index
