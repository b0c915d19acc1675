"""The task registry: :func:`register_task`, :func:`get_task`, :func:`task_names`, read live at each use.

Another package adds its tasks without touching this one, through the entry-point group
``snac_gym.tasks`` (as ``snac_gym.policies`` and ``snac_gym.robots``)::

    [project.entry-points."snac_gym.tasks"]
    mytask = "mypackage.tasks:MyTask"

An entry point names a :class:`~snac_gym.tasks.base.Task` subclass (built with no arguments) or an
instance; it is loaded and registered the first time the registry is read.
"""

from __future__ import annotations

from typing import Any

from snac_gym.common.entry_points import EntryPointGroup

#: The entry-point group of tasks from other packages.
ENTRY_POINT_GROUP = "snac_gym.tasks"
#: What a task class must set (the rest has defaults in :class:`~snac_gym.tasks.base.Task`).
REQUIRED_ATTRIBUTES = (
    "name",
    "label",
    "code",
    "option_key",
    "env_name",
    "success_tolerance",
    "episode_steps",
    "horizon_s",
    "real_horizon_s",
)
#: Registered tasks by name, in registration order (the order of reports and CSV columns). Read it through
#: :func:`task_names`, :func:`all_tasks` or :func:`get_task`, which load the entry points first.
TASKS: dict[str, Any] = {}
_ENTRY_POINTS = EntryPointGroup(ENTRY_POINT_GROUP)


def register_task(task: Any) -> Any:
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


def load_entry_points(rescan: bool = False) -> None:
    """Register the tasks of the ``snac_gym.tasks`` entry points not loaded yet: the installed packages are
    read on the first call of the process (``rescan=True``: again, after installing one at run time).

    Raises:
        ValueError: Naming the entry point whose object is not a task, or whose task cannot be registered.
    """
    for entry, loaded in _ENTRY_POINTS.new(rescan):
        task = loaded() if isinstance(loaded, type) else loaded
        try:
            if getattr(task, "name", None) not in TASKS or TASKS[task.name] is not task:
                register_task(task)
        except ValueError as error:
            raise ValueError(f"{_ENTRY_POINTS.name(entry)}: {error}") from None


def _is_task(value: Any) -> bool:
    return not isinstance(value, str) and all(hasattr(value, name) for name in REQUIRED_ATTRIBUTES)


def get_task(name: Any) -> Any:
    """The registered task called ``name`` (a task object is returned as is).

    Raises:
        ValueError: If there is none, naming the registered ones.
    """
    if _is_task(name):
        return name
    if name not in TASKS:
        load_entry_points()
    try:
        return TASKS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown task {name!r}; choose one of {list(TASKS)}") from None


def task_names() -> tuple[str, ...]:
    """Names of the registered tasks, in registration order (entry points included)."""
    load_entry_points()
    return tuple(TASKS)


def all_tasks() -> tuple[Any, ...]:
    """The registered tasks, in registration order (entry points included)."""
    load_entry_points()
    return tuple(TASKS.values())
