"""Gymnasium ids: one per robot, task and version, ``snac_gym/<Robot><Task>-v<version>``.

The robot part is :attr:`~snac_gym.model.robots.Robot.env_prefix` (``UR10``, ``Panda``, ``XArm7``),
the task part :attr:`~snac_gym.tasks.Task.env_name` (``Reach``, ``EllipseTrack``); the goal
variant appends ``Goal`` (``snac_gym/PandaReachGoal-v0``); :meth:`~snac_gym.tasks.Task.env_id_for` spells them.
:func:`snac_gym.envs.register_envs` registers every pair, as ``-v0`` (physical units) and ``-v1`` (the RL-ready
defaults), and records each id's robot, task and version here, in :data:`REGISTERED_IDS`.

An id drives the robot it names. ``robot=`` is still an argument of the env classes (that is how
one class serves every arm), but passing another robot than the id's to ``gym.make`` is refused
with a ``ValueError`` that names the right id (:func:`check_id_robot`): the id is what logs,
saved models, ``env.spec`` and videos record, so it must not say UR10 while a Panda moves.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from snac_gym.model.robots import get_robot
from snac_gym.tasks import get_task

if TYPE_CHECKING:
    from collections.abc import Callable


@dataclass(frozen=True)
class RegisteredId:
    """What a registered id runs: a robot, a task, plain or goal-conditioned."""

    robot: str
    task: str
    goal: bool = False
    version: int = 0


#: Every id :func:`snac_gym.envs.register_envs` registered, with its robot and task.
REGISTERED_IDS: dict[str, RegisteredId] = {}


def check_id_robot(spec: Any, robot: str) -> None:
    """Refuse an env built by ``gym.make`` for another robot than its id's.

    Called when ``gym.make`` (or ``make_vec``) sets ``env.spec``, right after construction.

    Args:
        spec: The ``EnvSpec`` being set (``None`` and ids not registered here pass).
        robot: The robot the env drives.

    Raises:
        ValueError: If the id names another robot; the message names the id to use.
    """
    registered = REGISTERED_IDS.get(getattr(spec, "id", None))  # type: ignore[arg-type]  # dict.get takes any key
    if registered is None:
        return
    driven = get_robot(robot)
    if driven.name == registered.robot:
        return
    right = get_task(registered.task).env_id_for(driven.name, goal=registered.goal, version=registered.version)
    raise ValueError(
        f"{spec.id} is the id of the {get_robot(registered.robot).description or registered.robot}; "
        f"for robot={robot!r} use gym.make({right!r})"
    )


class IdRobotCheck:
    """Mixin of the registered env classes: setting ``spec`` (``gym.make`` does) runs :func:`check_id_robot`.

    The env is closed before the error is raised, so a refused ``gym.make`` leaves no simulator open.
    An env given ``max_steps`` by ``gym.make`` warns (``DeprecationWarning``): under ``gym.make`` the
    episode length is Gymnasium's ``max_episode_steps``, whose ``TimeLimit`` also ends the episode.
    """

    _spec: Any = None

    if TYPE_CHECKING:
        close: Callable[..., None]  # the env's, of the class it is mixed into

    @property
    def spec(self) -> Any:
        """The ``EnvSpec`` ``gym.make`` built the env from (``None`` when constructed directly)."""
        return self._spec

    @spec.setter
    def spec(self, value: Any) -> None:
        try:
            check_id_robot(value, self.robot)
        except ValueError:
            self.close()
            raise
        requested = getattr(self, "requested_max_steps", None)
        if value is not None and requested is not None:
            warnings.warn(
                f"gym.make({value.id!r}, max_steps={requested}) is deprecated: pass max_episode_steps={requested} "
                "(the registration's TimeLimit also truncates, at its own length)",
                DeprecationWarning,
                stacklevel=3,
            )
        self._spec = value

    @property
    def robot(self) -> str:
        """The registered name of the robot this env drives."""
        raise NotImplementedError
