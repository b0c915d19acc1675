"""Parsing the text options of ``snac-gym evaluate`` into :class:`~snac_gym.evaluation.run_config.EvaluationConfig`
fields.

Each parser raises ``ValueError`` with a message naming the option and what was wrong.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from snac_gym.model.kinematics import Kinematics
from snac_gym.policies import available_policies
from snac_gym.sampling import REGIONS, SampleSpace
from snac_gym.tasks import PAPER_TASKS, task_names
from snac_gym.tasks.pose import is_pose_task, register_pose_tasks


def parse_out(text: str) -> Path:
    """The output folder; an empty or blank ``--out`` (which would be the current folder) is refused."""
    if not text.strip():
        raise ValueError("--out must name a folder, got an empty string")
    return Path(text)


def parse_tasks(text: str) -> tuple[str, ...]:
    """``both`` (the paper's ``reach`` and ``track``), a registered task (entry points included), or a pose task,
    ``pose-reach`` or ``pose-track`` (registered then)."""
    if text == "both":
        return PAPER_TASKS
    if text in task_names():
        return (text,)
    if is_pose_task(text):
        register_pose_tasks()
        return (text,)
    raise ValueError(
        f"--task must be both or a registered task ({', '.join(task_names())}), or a pose task "
        f"(pose-reach, pose-track), got {text!r}"
    )


def parse_controllers(text: str | None) -> tuple[str, ...] | None:
    """A comma-separated list of registered names, ``all`` or ``optimal`` among them (``None``: the default set)."""
    if text is None:
        return None
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if not names:
        raise ValueError(f"--controllers needs at least one name, got {text!r}")
    return names


def parse_horizons(values: Sequence[str], run_tasks: Sequence[str] = PAPER_TASKS) -> dict[str, float]:
    """``--horizon SECONDS`` (every task of the run) or ``--horizon TASK=SECONDS``, repeatable.

    A task given twice, or a task the run does not evaluate, is refused: one of the values would
    be silently ignored.
    """
    horizons: dict[str, float] = {}
    for text in values:
        task, _, seconds = text.rpartition("=")
        tasks = tuple(run_tasks) if not task else (task.strip(),)
        if tasks[0] not in task_names() and not is_pose_task(tasks[0]):
            raise ValueError(f"--horizon {text!r}: unknown task {task!r}; use reach=SECONDS or track=SECONDS")
        if task and tasks[0] not in run_tasks:
            raise ValueError(
                f"--horizon {text!r}: the run does not evaluate {tasks[0]!r} (--task); drop this --horizon"
            )
        if any(name in horizons for name in tasks):
            raise ValueError(
                f"--horizon {text!r}: a horizon for {', '.join(n for n in tasks if n in horizons)} is given twice"
            )
        try:
            value = float(seconds)
        except ValueError:
            raise ValueError(f"--horizon {text!r}: {seconds!r} is not a number of seconds") from None
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"--horizon {text!r}: the horizon must be a positive finite number of seconds")
        for name in tasks:
            horizons[name] = value
    return horizons


def parse_cuboid(text: str | None) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    """``x0,y0,z0,x1,y1,z1`` (m, base frame): the sample cuboid's low and high corners."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--cuboid {text!r}: six comma-separated numbers (m) are needed") from None
    if len(values) != 6:
        raise ValueError(f"--cuboid {text!r}: six numbers x0,y0,z0,x1,y1,z1 are needed, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"--cuboid {text!r}: every coordinate must be a finite number of metres")
    low, high = tuple(values[:3]), tuple(values[3:])
    if any(a >= b for a, b in zip(low, high, strict=True)):
        raise ValueError(f"--cuboid {text!r}: each low corner coordinate must be below the high one")
    return low, high  # type: ignore[return-value]


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def parse_params(values: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``--param CONTROLLER.KEY=VALUE``, repeatable (VALUE read as JSON, else as a string)."""
    params: dict[str, dict[str, Any]] = {}
    for text in values:
        target, sep, raw = text.partition("=")
        controller, dot, key = target.partition(".")
        if not sep or not dot or not controller or not key:
            raise ValueError(f"--param {text!r}: use CONTROLLER.KEY=VALUE, e.g. svf.nu=5")
        params.setdefault(controller.strip(), {})[key.strip()] = _value(raw.strip())
    return params


def check_option_combinations(
    *,
    samples: int | None,
    cuboid: str | None,
    samples_file: Path | None,
    export_samples: Path | None,
    sweep: bool,
    sweep_points: int | None,
    sweep_span: float | None,
    effort_reference: str | None,
    match_effort: bool,
    effort_target: float | None,
    controllers: Sequence[str] | None,
    sample_space: str = "cuboid",
    effort_samples: int | None = None,
) -> None:
    """Refuse an option that another one makes meaningless (it would be silently ignored), naming both."""
    if samples_file is not None:
        _check_with_samples_file(samples_file, samples, cuboid, sample_space, export_samples)
    if effort_samples is not None:
        _check_effort_samples(samples_file, match_effort)
    if not sweep:
        for given, option in ((sweep_points, "--sweep-points"), (sweep_span, "--sweep-span")):
            if given is not None:
                raise ValueError(f"{option} has no effect without --sweep; add --sweep or drop {option}")
    if effort_reference is not None:
        _check_effort_reference(effort_reference, match_effort, effort_target, controllers)


def _check_with_samples_file(
    samples_file: Path, samples: int | None, cuboid: str | None, sample_space: str, export_samples: Path | None
) -> None:
    if sample_space != "cuboid":
        raise ValueError("--sample-space has no effect with --samples-file (its rows are the samples); drop one")
    for given, option in ((samples, "--samples"), (cuboid, "--cuboid")):
        if given is not None:
            raise ValueError(f"{option} has no effect with --samples-file (its rows are the samples); drop {option}")
    if export_samples is not None and _same_file(samples_file, export_samples):
        raise ValueError(f"--export-samples {export_samples} is the --samples-file it reads; name another file")


def _check_effort_samples(samples_file: Path | None, match_effort: bool) -> None:
    if samples_file is not None:
        raise ValueError(
            "--effort-samples has no effect with --samples-file (its rows are the set); drop --effort-samples"
        )
    if not match_effort:
        raise ValueError("--effort-samples has no effect with --no-match-effort; drop one")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve() or (Path(b).exists() and Path(a).samefile(b))
    except OSError:
        return False


def _check_effort_reference(
    name: str, match_effort: bool, effort_target: float | None, controllers: Sequence[str] | None
) -> None:
    registered = available_policies()
    if name not in registered:
        raise ValueError(f"--effort-reference {name!r} names no registered controller; choose one of {registered}")
    if not match_effort:
        raise ValueError("--effort-reference has no effect with --no-match-effort; drop one of them")
    if effort_target is not None:
        raise ValueError("--effort-reference has no effect with --effort-target (every controller is matched to it)")
    if controllers is not None and name not in controllers:
        raise ValueError(f"--effort-reference {name!r} is not among --controllers {','.join(controllers)}; add it")


def parse_sample_space(name: str, cuboid: str | None, robot: str) -> Any:
    """``--sample-space cuboid`` (the default cuboid, or ``--cuboid``) or ``workspace`` (the arm's whole reach)."""
    if name not in REGIONS:
        raise ValueError(f"--sample-space must be one of {', '.join(REGIONS)}, got {name!r}")
    corners = parse_cuboid(cuboid)
    if name == "workspace":
        if corners is not None:
            raise ValueError(
                "--cuboid has no effect with --sample-space workspace (the box is the arm's reach); drop one"
            )
        return SampleSpace.workspace(Kinematics(robot))
    if corners is None:
        return None
    return SampleSpace.for_robot(Kinematics(robot), low=corners[0], high=corners[1])
