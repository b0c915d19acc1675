"""The controller contract, in one place: what every controller of snac-gym implements.

**The single protocol** (:class:`Policy`). A policy is built from the env it will drive
(:class:`PolicyContext` collects what it may take from there: the shared kinematics, the
control period, the limits, the observation layout and the task), then driven with
``reset(seed)`` and ``act(obs)``. The same object drives the PyBullet env, the evaluator's
kinematic engine and the real robot.

**The optional batch protocol.** A policy class MAY offer, besides the per-episode
``reset(seed)`` / ``act(obs)`` of :class:`snac_gym.policies.base.Policy`::

    def reset_batch(self, seeds: Sequence[int]) -> None:
        '''Start B independent episodes; episode i behaves as reset(seed=seeds[i]).'''

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        '''(B, d) observations, row i for episode i -> (B, m) commands.'''

One object then runs all B episodes of a chunk in lockstep, which lets it vectorise its
arithmetic across samples. Row ``i`` of ``act_batch`` must equal what a fresh object reset
with ``seeds[i]`` would return from ``act`` on the same observations (up to rounding), so
results do not depend on the protocol; ``internals`` are not read in batch mode. A class that
lacks either method is run the ordinary way: one object per sample, ``act`` called per row.

**The effort knob.** A class that declares ``effort_parameter = "<constructor argument>"``
can be matched to a common control effort by the evaluator (``snac-gym evaluate
--match-effort``): the argument must scale the commands' size monotonically (larger = more
aggressive), and ``effort_parameter_bounds = (low, high)`` may bound the search. Without it
the controller runs at its own settings.

**Registration.** :func:`snac_gym.policies.register_policy` (or the ``snac_gym.policies``
entry-point group) makes a class available by name to ``gym``-style construction,
``snac-gym demo --controller`` and ``snac-gym evaluate --controllers``. A complete
controller in under 30 lines is in docs/extending.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from snac_gym.kernels.compiled import read_only_view
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.model_error import refuse_pose_tasks
from snac_gym.observation import ObservationLayout
from snac_gym.tasks import Task, get_task


def _checked_float(name: str, value: Any, kind: str, allowed: Callable[[float], bool]) -> float:
    """``value`` as a finite float that ``allowed`` accepts, else ``ValueError`` naming ``kind``."""
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a {kind} number, got {value!r}") from exc
    if not (np.isfinite(number) and allowed(number)):
        raise ValueError(f"{name} must be a {kind} finite number, got {value!r}")
    return number


def positive_float(name: str, value: Any) -> float:
    """``value`` as a finite float > 0 (``ValueError`` otherwise)."""
    return _checked_float(name, value, "positive", lambda number: number > 0)


def non_negative_float(name: str, value: Any) -> float:
    """``value`` as a finite float ≥ 0 (``ValueError`` otherwise)."""
    return _checked_float(name, value, "non-negative", lambda number: number >= 0)


def scale_rows_into_limits(commands: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Each row of ``commands`` ``(B, m)`` (or one ``(m,)``) divided by its largest ``|uⱼ|/limitⱼ`` where that
    exceeds 1.

    The uniform scaling into the velocity limits that the resolved-rate baselines, LQR, the critics and the PPO
    maps share: the direction of u, and of ė = J u, is kept (:func:`snac_gym.baselines._common.scale_into_box` is
    the one-row form that also returns the factor).
    """
    rows, bounds = np.asarray(commands), np.asarray(limits)
    if (
        rows.ndim in (1, 2)
        and rows.shape[-1] > 0
        and bounds.shape == rows.shape[-1:]
        and rows.dtype.kind in "fiu"
        and bounds.dtype.kind in "fiu"
        and np.result_type(rows, bounds) == np.float64
    ):  # the controllers' case, compiled: the same bits in under a third of the time (docs/benchmarks-log.md)
        from snac_gym.kernels.small import scale_rows  # numba: imported where first needed

        scaled_rows: np.ndarray = scale_rows(read_only_view(rows.reshape(-1, rows.shape[-1])), read_only_view(bounds))
        return scaled_rows.reshape(rows.shape)
    scales = np.max(np.abs(commands) / limits, axis=-1, keepdims=True)
    scaled = commands / np.maximum(scales, 1.0)
    # u/scale can land one rounding step outside the limit it was scaled onto.
    within: np.ndarray = np.minimum(np.maximum(scaled, -limits), limits)
    return within


@runtime_checkable
class Policy(Protocol):
    """What the envs, the evaluator and the real-robot loop need from a controller.

    Attributes:
        internals: A dict of named arrays describing the policy's state after the last
            ``act`` call (for example ``critic_weights`` and ``lyapunov`` for SNAC), read by
            the trajectory logs. Empty for policies with nothing to expose.
    """

    internals: dict[str, Any]

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode; ``seed`` fixes any randomness (e.g. initial critic weights)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command u (rad/s, shape ``(n_joints,)``) for observation ``obs``."""


@dataclass(frozen=True)
class PolicyContext:
    """What a policy takes from the env it drives.

    Attributes:
        kinematics: The shared :class:`~snac_gym.model.kinematics.Kinematics`.
        dt: Control period, s.
        velocity_limits: Joint speed limits, rad/s (the action bounds).
        layout: The observation layout.
        task: The task's name (a registered :class:`~snac_gym.tasks.Task`).
        arm: The robot the env drives, when the kinematics is another robot's model
            (``--model-error model=NAME``); ``None``: ``kinematics.robot``.
    """

    kinematics: Kinematics
    dt: float
    velocity_limits: np.ndarray
    layout: ObservationLayout
    task: str
    arm: str | None = None

    @property
    def arm_robot(self) -> str:
        """The name of the robot the env drives (whatever model the controller was given)."""
        return self.arm if self.arm is not None else self.kinematics.robot

    def __post_init__(self) -> None:
        object.__setattr__(self, "task", get_task(self.task).name)  # a Task may be given; keep its name
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")

    @property
    def task_spec(self) -> Task[Any]:
        """The :class:`~snac_gym.tasks.Task` (its success rule, whether x_d moves, ...)."""
        task: Task[Any] = get_task(self.task)
        return task

    def with_model_error(self, model_error: Any) -> PolicyContext:
        """This context with the arm model a wrong one (:class:`~snac_gym.model.model_error.ModelError` or its text).

        Only the controller's kinematics change; whatever it drives keeps the true arm.

        Raises:
            ValueError: For a malformed error, or on a pose task (position kinematics only).
        """
        if not isinstance(self.kinematics, Kinematics):
            refuse_pose_tasks([self.task_name])
        return dataclasses.replace(self, kinematics=self.kinematics.with_model_error(model_error), arm=self.arm_robot)

    @classmethod
    def for_controller(cls, env: Any, model_error: Any = None) -> Any:
        """What to build a controller from: ``env`` itself, or with ``model_error`` its context on the wrong model."""
        return env if model_error is None else cls.from_env(env).with_model_error(model_error)

    @classmethod
    def from_env(cls, env: Any) -> PolicyContext:
        """Read the context from a snac-gym env (wrapped or not) or from a context itself."""
        if isinstance(env, PolicyContext):
            return env
        base = getattr(env, "unwrapped", env)
        missing = [
            a for a in ("kinematics", "dt", "velocity_limits", "obs_layout", "task_name") if not hasattr(base, a)
        ]
        if missing:
            raise TypeError(f"{type(base).__name__} is not a snac-gym env: it lacks {missing}")
        return cls(
            base.kinematics, float(base.dt), np.asarray(base.velocity_limits, float), base.obs_layout, base.task_name
        )


class BasePolicy:
    """Convenience base class: stores the context, gives ``internals`` a default, and checks what ``act`` is given.

    A subclass implements :meth:`_act`; :meth:`act` (a template method) refuses anything but a real, finite
    observation of the layout's size with a ``ValueError`` naming the class, then calls it: a NaN observation (a
    failed sensor read, a diverged state) never turns into a NaN command. (About 2 µs a call; the batch protocol is
    not checked.) A subclass that overrides ``act`` itself does its own checks.
    """

    def __init__(self, env: Any) -> None:
        self.context = PolicyContext.from_env(env)
        self.kinematics = self.context.kinematics
        self.dt = self.context.dt
        self.velocity_limits = self.context.velocity_limits
        self.layout = self.context.layout
        self.task = self.context.task
        #: Whether the reference moves (tracking): ẋ_d is then part of the problem.
        self.tracking = self.context.task_spec.moving_reference
        self.internals: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        self.internals = {}

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command u (rad/s) for one observation: :meth:`_act` of the checked observation."""
        observation = np.asarray(obs)
        size = self.layout.size
        if observation.dtype.kind not in "iuf" or observation.shape != (size,) or not np.isfinite(observation).all():
            finite = observation.dtype.kind not in "iuf" or np.isfinite(observation).all()
            raise ValueError(
                f"{type(self).__name__}.act needs a finite observation of shape ({size},), got "
                f"{observation.dtype} {observation.shape}" + ("" if finite else " with NaN or inf")
            )
        return self._act(observation)

    def _act(self, obs: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """The command for a checked observation (a subclass's control law)."""
        raise NotImplementedError(f"{type(self).__name__} implements no _act")


def supports_batch(policy: Any) -> bool:
    """Whether ``policy`` (an instance or a class) offers ``reset_batch`` and ``act_batch``."""
    return callable(getattr(policy, "reset_batch", None)) and callable(getattr(policy, "act_batch", None))


class LockstepPolicies:
    """B episodes of one controller, stepped together.

    Args:
        make_policy: Builds one policy object (called once in batch mode, B times otherwise).
        seeds: Reset seed of each episode.
        use_batch: Use the batch protocol when the policy offers it (default ``True``);
            ``False`` forces the per-sample path (the tests compare the two).
    """

    def __init__(self, make_policy: Callable[[], Any], seeds: Sequence[int], use_batch: bool = True) -> None:
        self.seeds = [int(s) for s in seeds]
        first = make_policy()
        self.batched = bool(use_batch and supports_batch(first))
        if self.batched:
            self._batch_policy = first
            first.reset_batch(self.seeds)
            self._policies: list[Any] = []
        else:
            self._policies = [first] + [make_policy() for _ in self.seeds[1:]]
            for policy, seed in zip(self._policies, self.seeds, strict=True):
                policy.reset(seed=seed)

    @property
    def critic(self) -> Any:
        """The ``critic_diagnostics`` method of a critic-based controller, else ``None``."""
        return getattr(self._batch_policy if self.batched else self._policies[0], "critic_diagnostics", None)

    def critic_weights(self) -> np.ndarray:
        """``(B, l)``: each episode's critic weights now (those its next command uses)."""
        if self.batched:
            return np.array(self._batch_policy.batch_critic_weights, dtype=float)
        return np.array([policy.critic_weights for policy in self._policies], dtype=float)

    def episode_flags(self) -> dict[str, np.ndarray] | None:
        """Each episode's flags of a controller that watches itself (``episode_flags()``), else ``None``."""
        if self.batched:
            flags = getattr(self._batch_policy, "episode_flags", None)
            return None if flags is None else flags()
        if not hasattr(self._policies[0], "episode_flags"):
            return None
        rows = [policy.episode_flags() for policy in self._policies]
        return {name: np.concatenate([row[name] for row in rows]) for name in rows[0]}

    def act(self, observations: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, d)`` (row i to episode i)."""
        if self.batched:
            return np.asarray(self._batch_policy.act_batch(observations), dtype=float)
        return np.array(
            [policy.act(obs) for policy, obs in zip(self._policies, observations, strict=True)], dtype=float
        )
