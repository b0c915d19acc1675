"""The tasks: ``get_task("reach")``, ``get_task("track")``, the registry (:mod:`snac_gym.tasks.registry`) and
:func:`register_task`.

See docs/extending.md for adding a task in one module.
"""

from __future__ import annotations

from snac_gym.tasks.base import Sample, Task
from snac_gym.tasks.reach import ReachTask
from snac_gym.tasks.registry import REQUIRED_ATTRIBUTES, TASKS, all_tasks, get_task, register_task, task_names
from snac_gym.tasks.track import EllipseTrackTask

#: The paper's two tasks, in Table I's order: what ``snac-gym evaluate`` runs unless ``--tasks`` says otherwise.
PAPER_TASKS = ("reach", "track")

register_task(ReachTask())
register_task(EllipseTrackTask())

__all__ = [
    "PAPER_TASKS",
    "REQUIRED_ATTRIBUTES",
    "TASKS",
    "EllipseTrackTask",
    "ReachTask",
    "Sample",
    "Task",
    "all_tasks",
    "get_task",
    "register_task",
    "task_names",
]
