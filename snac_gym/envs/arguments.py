"""The checks of the env's arguments and ``reset`` options, and the episode's draw.

Shared by the simulated env (:mod:`snac_gym.envs.core`), the batched vector env (:mod:`snac_gym.envs.vector`) and
the real-arm env (:mod:`snac_gym.real.env`), so that each refuses a bad input alike, with the same message, and the
same seed gives the same episode.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, TypeVar

import numpy as np

from snac_gym.envs.rewards import REWARD_TYPES
from snac_gym.model.kinematics import Kinematics
from snac_gym.physics import PHYSICS, check_physics
from snac_gym.sampling import REGIONS, SampleSpace, sample_seed_pose
from snac_gym.tasks import Task

__all__ = [
    "ACTION_TYPES",
    "MAX_EPISODE_STEPS",
    "MAX_SUCCESS_TOLERANCE",
    "OBSERVATION_BOUNDS",
    "OBSERVATION_DTYPES",
    "V1_DEFAULTS",
    "ActionCheck",
    "check_choices",
    "check_observation_bounds",
    "check_sample_space",
    "draw_episode",
    "physics_argument",
    "resolve_reference",
    "validate_action",
    "validate_q0",
]

#: The reference type of the episode's task (a target, an ellipse, a pose target, ...).
_ReferenceT = TypeVar("_ReferenceT")
#: Action types: joint velocities in rad/s, or [−1, 1] per joint scaled to the velocity limits.
ACTION_TYPES = ("velocity", "normalized")
#: Observation dtypes.
OBSERVATION_DTYPES = (np.dtype(np.float64), np.dtype(np.float32))
#: Values of ``finite_observation_bounds``: ±inf (``False``), the physical bounds with θ̇ unbounded
#: (``True``), or every field bounded and the observation clipped into the bounds (``"clip"``, the -v1 default).
OBSERVATION_BOUNDS = (False, True, "clip")
#: The defaults of the -v1 ids (:func:`snac_gym.envs.register_envs`): normalized float32 actions,
#: float32 observations with finite bounds on every field, PyBullet's motors solved directly (docs/physics.md). The
#: -v0 ids keep the constructor's defaults.
V1_DEFAULTS: Mapping[str, Any] = MappingProxyType(
    {
        "action_type": "normalized",
        "observation_dtype": "float32",
        "finite_observation_bounds": "clip",
        "pybullet_solver": "dantzig",
    }
)


#: Largest ``success_tolerance``, m: a tolerance above a metre counts most of a UR arm's reach (0.5 m to 1.3 m) as
#: reached, so no success rate would measure anything.
MAX_SUCCESS_TOLERANCE = 1.0


def check_sample_space(value: Any, kinematics: Kinematics) -> SampleSpace:
    """``sample_space`` as a :class:`~snac_gym.sampling.SampleSpace`: one given, ``None`` (the robot's cuboid) or a
    region's name, ``"cuboid"`` (the same) or ``"workspace"`` (:meth:`SampleSpace.workspace`).

    Raises:
        ValueError: Naming ``sample_space`` and the valid names, for anything else.
    """
    if value is None or (isinstance(value, str) and value == "cuboid"):
        return SampleSpace.for_robot(kinematics)
    if isinstance(value, str) and value == "workspace":
        return SampleSpace.workspace(kinematics)
    if not isinstance(value, SampleSpace):
        raise ValueError(
            "sample_space must be a snac_gym.sampling.SampleSpace, None or one of "
            f"{', '.join(map(repr, REGIONS))}, got {value!r}"
        )
    return value


#: Longest episode an env accepts, control steps (about 22 hours at 125 Hz): a bound on what a typo can cost.
MAX_EPISODE_STEPS = 10_000_000


def validate_action(action: Any, velocity_limits: np.ndarray) -> np.ndarray:
    """The joint-velocity command an env applies: checked, then clipped to ``±velocity_limits``.

    Shared by the simulated and the real-robot envs so both treat bad input alike.

    Raises:
        ValueError: If ``action`` is not numeric, has the wrong shape, or holds NaN/inf.
    """
    try:
        raw = np.asarray(action)
        if raw.dtype.kind not in "iuf":  # a complex, bool or string action is refused, not cast
            raise TypeError(raw.dtype)
        u = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"action must be {len(velocity_limits)} joint velocities in rad/s (real numbers), got {action!r}"
        ) from exc
    if u.shape != velocity_limits.shape:
        raise ValueError(f"action must have shape {velocity_limits.shape} (joint velocities, rad/s), got {u.shape}")
    if not np.isfinite(u).all():
        raise ValueError(f"action contains NaN or inf: {u.tolist()}")
    clipped: np.ndarray = np.minimum(np.maximum(u, -velocity_limits), velocity_limits)
    return clipped


class ActionCheck:
    """:func:`validate_action` for one env's limits, its constants set up once (at construction).

    The common action, an exact ``ndarray`` of float64 or float32 of the right shape, is checked by
    one ``isfinite`` count and clipped by two ufuncs into one new float64 array; the same values as
    :func:`validate_action`, which every other input (and every refusal, with its message) goes through.

    Args:
        limits: The velocity limits (rad/s; ones for a normalized action), a read-only float64 array.
    """

    __slots__ = ("limits", "_low", "_shape", "_size")

    def __init__(self, limits: np.ndarray) -> None:
        self.limits = limits
        self._low = -limits
        self._shape = limits.shape
        self._size = limits.size

    def __call__(self, action: Any) -> np.ndarray:
        # float64 or float32 ('d', 'f'; either byte order): np.maximum with the float64 bounds gives what
        # np.array(action, dtype=np.float64) would be before the clip, and a new array the env may keep.
        # Every value finite: counted (count_nonzero is a C call, ndarray.all a Python wrapper at twice the cost).
        if (
            type(action) is np.ndarray
            and action.dtype.char in "df"
            and action.shape == self._shape
            and np.count_nonzero(np.isfinite(action)) == self._size
        ):
            u = np.maximum(action, self._low)
            clipped: np.ndarray = np.minimum(u, self.limits, out=u)
            return clipped
        return validate_action(action, self.limits)


def resolve_reference(
    task: Task[_ReferenceT],
    kinematics: Kinematics,
    rng: np.random.Generator,
    space: SampleSpace,
    options: Mapping[str, Any] | None,
) -> _ReferenceT:
    """The episode's reference from ``reset`` options (shared by the simulated and real envs).

    No options: a random reference from ``space``. Options without the task's key: the paper's
    reference. Otherwise the given one, checked to be reachable.

    Raises:
        ValueError: On unknown keys, a malformed or an unreachable reference.
    """
    if options is None:
        return task.sample(kinematics, rng, space)
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a dict, got {type(options).__name__}")
    unknown = set(options) - {"q0", task.option_key}
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown)}; allowed: ['q0', '{task.option_key}']")
    if task.option_key in options:
        return task.parse(options[task.option_key], kinematics)
    return task.paper()


def validate_q0(kinematics: Kinematics, value: Any) -> np.ndarray:
    """``options["q0"]`` as an array, checked against the joint count and limits."""
    q0 = np.array(value, dtype=float)
    if q0.shape != (kinematics.n_joints,) or not np.all(np.isfinite(q0)):
        raise ValueError(f"options['q0'] must be {kinematics.n_joints} finite joint angles, got {value!r}")
    outside = np.flatnonzero((q0 < kinematics.lower_limits) | (q0 > kinematics.upper_limits))
    if outside.size:
        j = int(outside[0])
        raise ValueError(
            f"options['q0'][{j}] = {q0[j]} rad is outside the joint limits "
            f"[{kinematics.lower_limits[j]}, {kinematics.upper_limits[j]}]"
        )
    return q0


def draw_episode(
    task: Task[_ReferenceT],
    kinematics: Kinematics,
    rng: np.random.Generator,
    space: SampleSpace,
    options: Mapping[str, Any] | None,
) -> tuple[np.ndarray, _ReferenceT]:
    """The start pose and the reference of one episode, as ``reset`` draws them.

    The reference is drawn (or read from ``options``) first, then the seed pose, both from
    ``rng``: the single env and the batched vector env (:mod:`snac_gym.envs.vector`) call this
    with each episode's generator, so the same seed gives the same episode in both.

    Raises:
        ValueError: On bad options (see :func:`resolve_reference` and :func:`validate_q0`).
    """
    reference = resolve_reference(task, kinematics, rng, space, options)
    q0 = None if options is None else options.get("q0")
    if q0 is None:
        return sample_seed_pose(kinematics, rng, space), reference
    return validate_q0(kinematics, q0), reference


def physics_argument(physics: str, backend: str | None = None) -> str:
    """The ``physics=`` argument, or the deprecated ``backend=`` one (with a ``DeprecationWarning``).

    Raises:
        ValueError: If it is not one of :data:`~snac_gym.physics.PHYSICS`, or both are given and differ.
    """
    if backend is not None:
        warnings.warn(
            f"backend={backend!r} is deprecated; use physics={backend!r} (the arm's model: one of {PHYSICS})",
            DeprecationWarning,
            stacklevel=3,
        )
        if physics not in (backend, PHYSICS[0]):
            raise ValueError(
                f"give physics= only (backend= is its deprecated name), got physics={physics!r}, backend={backend!r}"
            )
        physics = backend
    return check_physics(physics)


def check_observation_bounds(value: Any) -> bool | str:
    """``finite_observation_bounds`` checked: ``False``, ``True`` or ``"clip"`` (:data:`OBSERVATION_BOUNDS`).

    Raises:
        ValueError: For any other value.
    """
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if value == "clip":
        return "clip"
    raise ValueError(f"finite_observation_bounds must be False, True or 'clip', got {value!r}")


def check_choices(
    reward_type: str, action_type: str, observation_dtype: Any, render_mode: str | None, metadata: Mapping[str, Any]
) -> np.dtype:
    """Check the env's enumerated arguments; returns the observation dtype.

    Raises:
        ValueError: Naming the argument and its allowed values.
    """
    if reward_type not in REWARD_TYPES:
        raise ValueError(f"reward_type must be one of {REWARD_TYPES}, got {reward_type!r}")
    if action_type not in ACTION_TYPES:
        raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
    obs_dtype: np.dtype | None
    try:
        obs_dtype = np.dtype(observation_dtype)
    except TypeError:
        obs_dtype = None
    if obs_dtype not in OBSERVATION_DTYPES:
        raise ValueError(f"observation_dtype must be np.float64 or np.float32, got {observation_dtype!r}")
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}")
    return obs_dtype
