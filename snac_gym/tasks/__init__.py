"""The task registry: ``get_task("reach")``, ``get_task("track")``, and :func:`register_task`.

See docs/extending.md for adding a task in one module.
"""

from __future__ import annotations

from snac_gym.tasks.base import Sample, Task
from snac_gym.tasks.reach import ReachTask
from snac_gym.tasks.track import EllipseTrackTask

#: What a task class must set (the rest has defaults in :class:`Task`).
REQUIRED_ATTRIBUTES = (
    "name", "label", "code", "option_key", "env_name", "success_tolerance",
    "episode_steps", "horizon_s", "real_horizon_s",
)
#: Registered tasks by name, in registration order (the order of reports and CSV columns).
TASKS: dict[str, Task] = {}


def register_task(task: Task) -> Task:
    """Add ``task`` to :data:`TASKS` (its name and spawn-key code must be new).

    Raises:
        ValueError: If a required attribute is missing, or the name or the code is taken.
    """
    missing = [name for name in REQUIRED_ATTRIBUTES if not hasattr(task, name)]
    if missing:
        raise ValueError(f"task {type(task).__name__} does not set {missing} (see snac_gym.tasks.base.Task)")
    if task.name in TASKS:
        raise ValueError(f"a task named {task.name!r} is already registered")
    taken = {other.code: other.name for other in TASKS.values()}
    if task.code in taken:
        raise ValueError(f"task {task.name!r}: sample code {task.code} is already used by {taken[task.code]!r}")
    TASKS[task.name] = task
    return task


def get_task(name: str | Task) -> Task:
    """The registered task called ``name`` (a :class:`Task` is returned as is).

    Raises:
        ValueError: If there is none, naming the registered ones.
    """
    if isinstance(name, Task):
        return name
    try:
        return TASKS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown task {name!r}; choose one of {list(TASKS)}") from None


def task_names() -> tuple[str, ...]:
    """Names of the registered tasks, in registration order."""
    return tuple(TASKS)


register_task(ReachTask())
register_task(EllipseTrackTask())

__all__ = ["TASKS", "EllipseTrackTask", "ReachTask", "Sample", "Task", "get_task", "register_task", "task_names"]
