"""What ``snac-gym real`` checks before anything connects: the arm, the start pose, the reference, the limits and
whether missed deadlines stop the arm.

Part of :mod:`snac_gym.apps.real`: a run refused here has touched no arm, and ``--dry-run`` prints what it settled.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from snac_gym.envs.core import resolve_reference, validate_q0
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS, get_ur_model, series_of, velocity_limits
from snac_gym.real.safety import SafetyLayer, SafetyLimits
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

__all__ = ["MAX_REAL_SECONDS", "UR_ROBOTS", "is_rehearsal", "resolve_deadline_stop", "run_setup"]

#: Longest episode ``snac-gym real`` runs, s (``--steps`` is bounded by it at 500 Hz): an hour of streaming.
MAX_REAL_SECONDS = 3600.0
#: The arms ``snac-gym real`` drives: the UR models of the registry (ur_rtde; ``snac-gym emulate-ur`` serves the same).
UR_ROBOTS = tuple(UR_MODELS)


def is_rehearsal(connection: str, dry_run: bool) -> bool:
    """Whether a run is a rehearsal: a simulated arm (``sim``) or a dry run, where nothing reaches an arm."""
    return connection == "sim" or dry_run


def resolve_deadline_stop(
    safety: SafetyLimits, connection: str, dry_run: bool, deadline_stop: bool | None
) -> SafetyLimits:
    """``safety`` with the run's deadline stop: ``deadline_stop`` if given, else on for a real (or emulated) arm
    and off for a rehearsal (:func:`is_rehearsal`: late periods are then only counted and reported).

    Raises:
        ValueError: If the deadline stop would be off for an arm that moves (``--connection rtde`` without
            ``--dry-run``): a late loop there is a hazard, not a statistic.
    """
    rehearsal = is_rehearsal(connection, dry_run)
    stop = (safety.deadline_stop and not rehearsal) if deadline_stop is None else bool(deadline_stop)
    if not stop and not rehearsal:
        raise ValueError(
            "--no-deadline-stop is for a rehearsal (--connection sim or --dry-run): "
            "on a real or emulated arm missed deadlines stop it"
        )
    return replace(safety, deadline_stop=stop)


def run_setup(
    task: str, robot: str, q0: Sequence[float] | None, reference: Any, safety: SafetyLimits, series: str | None = None
) -> dict[str, Any]:
    """The checked start pose, reference and limits of a real run, before anything connects; ``*_real.json``
    records it and the dry run prints it.

    ``q0`` and ``reference`` (the task's reset-option value, e.g. the target ``[x, y, z]`` of reach) default to
    the paper's (``snac-gym demo``'s), which the UR10 reaches; the smaller arms need their own.

    Raises:
        ValueError: Naming what is wrong: a robot that is not a UR arm, a series it does not run at, a start pose
            outside the joint limits or the safety margins, an unreachable reference or one beyond the
            datasheet's reach (from the shoulder), or a start or reference outside the task box.
    """
    if robot not in UR_ROBOTS:
        raise ValueError(f"--robot must be one of {', '.join(UR_ROBOTS)} (the UR arms ur_rtde drives), got {robot!r}")
    series = series_of(robot, series)
    spec, kinematics = get_task(task), Kinematics(robot)
    options = spec.demo_options()
    if q0 is not None:
        options["q0"] = [float(v) for v in q0]
    if reference is not None:
        options[spec.option_key] = reference
    hint = (
        ""
        if robot == "ur10" or (q0 is not None and reference is not None)
        else f" (the paper's start pose and reference are the UR10's: give --q0 and the reference for {robot}"
        + ("" if reference is not None else _scaled_reference_hint(task, robot))
        + ")"
    )
    try:
        start = validate_q0(kinematics, options["q0"])
        resolved = resolve_reference(
            spec, kinematics, np.random.default_rng(0), SampleSpace.for_robot(kinematics), options
        )
    except ValueError as exc:
        raise ValueError(re.sub(r"options\['(\w+)'\]", r"--\1", str(exc)) + hint) from None
    layer = SafetyLayer(kinematics, safety, 1.0)
    violation = layer.pose_violation(start, kinematics.forward(start))
    if violation is not None:
        raise ValueError(f"--q0 is outside the safety limits: {violation}{hint}")
    points = np.atleast_2d(resolved.points(64))
    model = get_ur_model(robot)
    shoulder = np.array([0.0, 0.0, model.dh[0]])
    distances = np.linalg.norm(points - shoulder, axis=1)
    farthest = int(np.argmax(distances))
    if distances[farthest] > model.reach:
        raise ValueError(
            f"the {task} reference reaches [{_fmt(points[farthest])}] m, {distances[farthest]:.3f} m from "
            f"the shoulder: beyond the {model.label}'s datasheet reach of {model.reach:.3f} m{hint}"
        )
    low, high = safety.task_box(kinematics)
    outside = [p for p in points if np.any(p < low) or np.any(p > high)]
    if outside:
        raise ValueError(
            f"the {task} reference leaves the task box [{_fmt(low)}] .. [{_fmt(high)}] m at "
            f"[{_fmt(outside[0])}]: choose another reference, or --task-box{hint}"
        )
    return {
        "robot": robot,
        "task": task,
        "q0": [float(v) for v in start],
        spec.option_key: options[spec.option_key],
        "task_box": [low.tolist(), high.tolist()],
        "joint_limit_margin": safety.joint_limit_margin,
        "speed_scale": safety.speed_scale,
        "max_joint_acceleration": safety.max_joint_acceleration,
        "series": series,
        "speed_limits": [float(v) for v in velocity_limits(robot, kinematics.velocity_limits)],
        "speed_limits_source": f"the URDF's, capped at the {model.source['speeds']}",
        "reach": model.reach,
        "deadline_stop": safety.deadline_stop,
    }


def _scaled_reference_hint(task: str, robot: str) -> str:
    """``; --target=… is the paper's scaled to the UR5, as `snac-gym demo --robot ur5` runs it``: the options of the
    reference :meth:`~snac_gym.tasks.base.Task.demo_options` gives ``robot`` (empty for a task without them here)."""
    spec = get_task(task)
    value = spec.demo_options(robot).get(spec.option_key)
    if task == "reach":
        options = f"--target={','.join(f'{v:.3f}' for v in value)}"
    elif task == "track" and isinstance(value, dict) and len(set(value["semi_axes"])) == 1:
        centre = ",".join(f"{v:.3f}" for v in value["centre"])
        options = f"--ellipse-centre={centre} --ellipse-radius={value['semi_axes'][0]:.3f}"
    else:
        return ""
    label = get_ur_model(robot).label
    return f"; {options} is the paper's scaled to the {label}, as `snac-gym demo --robot {robot}` runs it"


def _fmt(values: Any) -> str:
    return ", ".join(f"{v:.3f}" for v in np.asarray(values, dtype=float))
