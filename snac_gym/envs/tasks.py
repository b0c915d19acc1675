"""Deprecated location of the tasks: use :mod:`snac_gym.tasks` (kept until every importer moves)."""

from snac_gym.tasks import TASKS as _REGISTRY
from snac_gym.tasks import EllipseTrackTask, ReachTask, Task

TASKS = {name: type(task) for name, task in _REGISTRY.items()}

__all__ = ["TASKS", "EllipseTrackTask", "ReachTask", "Task"]
