"""Parsing the text options of ``snac-gym evaluate`` into :class:`~evaluation.run_config.EvaluationConfig` fields.

Each parser raises ``ValueError`` with a message naming the option and what was wrong.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from evaluation.samples import TASKS
from snac_gym.tasks.pose import is_pose_task, register_pose_tasks


def parse_out(text: str) -> Path:
    """The output folder; an empty or blank ``--out`` (which would be the current folder) is refused."""
    if not text.strip():
        raise ValueError("--out must name a folder, got an empty string")
    return Path(text)


def parse_tasks(text: str) -> tuple[str, ...]:
    """``reach``, ``track`` or ``both``; or a pose task, ``pose-reach`` or ``pose-track`` (registered then)."""
    if text == "both":
        return TASKS
    if text in TASKS:
        return (text,)
    if is_pose_task(text):
        register_pose_tasks()
        return (text,)
    raise ValueError(f"--task must be reach, track or both, or a pose task (pose-reach, pose-track), got {text!r}")


def parse_controllers(text: str | None) -> tuple[str, ...] | None:
    """A comma-separated list of registered names (``None``: every registered controller)."""
    if text is None:
        return None
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if not names:
        raise ValueError(f"--controllers needs at least one name, got {text!r}")
    return names


def parse_horizons(values: Sequence[str]) -> dict[str, float]:
    """``--horizon SECONDS`` (every task) or ``--horizon TASK=SECONDS``, repeatable."""
    horizons: dict[str, float] = {}
    for text in values:
        task, _, seconds = text.rpartition("=")
        tasks = TASKS if not task else (task.strip(),)
        if tasks[0] not in TASKS and not is_pose_task(tasks[0]):
            raise ValueError(f"--horizon {text!r}: unknown task {task!r}; use reach=SECONDS or track=SECONDS")
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
