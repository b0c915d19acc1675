"""What the PPO network sees and what its output means: features from the observation alone,
and the map from the normalised action to joint velocities.

Both are used at training time (by :class:`snac_gym.ppo.envs.PPOTrainingWrapper`) and at run
time (by :class:`snac_gym.ppo.policy.PPOPolicy`), so the two cannot drift apart. The features
are computed from the observation vector only (through its :class:`ObservationLayout`), never
from simulator state, so the same policy runs on the PyBullet env, the evaluator's kinematic
engine and the real robot.

Features (``FEATURE_VERSION`` 2), for m joints and task dimension n:

====================  ======  ==============================================================
feature               size    meaning
====================  ======  ==============================================================
sin q, cos q          2m      joint angles on the circle (the arm's configuration)
e / coarse            n       task error e = x − x_d scaled by ``error_scale_coarse`` (m)
tanh(e / fine)        n       the error magnified by ``error_scale_fine`` (m), squashed:
                              the resolution needed to settle within millimetres
log10(‖e‖ + ε)        1       the error's magnitude on a log scale (ε = 1e-4 m)
ẋ_d / velocity        n       desired velocity scaled by ``velocity_scale`` (m/s): the
                              tracking feed-forward (zero for reach)
(x − x₀) / position   n       end-effector position about ``position_centre`` (m), scaled
                              by ``position_scale`` (m)
ln(action_scale)      1       the effort knob the policy runs with (see below)
====================  ======  ==============================================================

The joint-velocity field of the observation is not used: the kinematic engine fills it
with the previous command while the PyBullet env measures it, so it is not the same
signal everywhere.

Two kinds of policy (``FeatureSpec.action``):

``"task-relative"`` (``FEATURE_VERSION`` 3, the shipped policies): the network chooses an
end-effector velocity *relative to the error*, and the kinematic model's damped pseudo-inverse
(the map DLS uses) turns it into joint velocities:

    v = ẋ_d + action_scale · gain_max · (‖e‖ + ε_v) · a,    u = Jᵀ(JJᵀ + λ²I)⁻¹ v,   clipped to ±ū

with a ∈ [−1, 1]ⁿ (n = task dimension), ε_v = 0.1 mm. The network sees only scale-free features:

====================  ======  ==============================================================
feature               size    meaning
====================  ======  ==============================================================
e / ‖e‖               n       the error's direction
log‖e‖                1       its magnitude, (log10(‖e‖ + 10⁻⁵ m) + 2.5) / 1.5
ẋ_d / velocity        n       the reference's velocity (zero for reach)
ẋ_d / (‖e‖ + 1 mm)    n       the same relative to the error, / 10
e / (2·coarse)        n       the error itself (the critic's quadratic cost needs it)
====================  ======  ==============================================================

The effort knob ``action_scale`` is not an input here: it multiplies the feedback gain, which
the scale-free action keeps a stable linear loop for any gain a 125 Hz step allows, and a
network trained to minimise one cost would learn to cancel a knob it could see.

Why: a joint-space network has to learn the arm's kinematics from sin/cos θ and, under a
reward equal to the quadratic cost, gets almost no signal in the last millimetres (the cost
there is ~10⁻⁶ of the start's), so it neither beats the resolved-rate baselines nor settles
to 1 mm. Here ``a`` is a gain per unit of error: a constant ``a = −(k/gain_max)·e/‖e‖`` is the
resolved-rate law of gain k at every scale, so what the network learns at centimetres holds at
micrometres, and the feed-forward ẋ_d is built in. What is learnt is the gain and direction of
the feedback as functions of the error and the reference; the kinematics are the model's.

``"goal-relative"`` (``FEATURE_VERSION`` 4, the workspace policies): the task-relative action plus one
more output, a joint-space gain towards a goal configuration inside the joint limits
(:mod:`snac_gym.model.joint_goal`: the in-limit IK solution nearest θ₀, carried along a moving reference by
a virtual arm θ*(t) with velocity θ̇*):

    u = sat(θ̇* + s·joint_gain·(1 + a₀)·(θ* − θ) + Jᵀ(JJᵀ + λ²I)⁻¹ (s·gain_max·(‖e‖ + ε_v)·a₁..ₙ))

with ``sat`` the uniform scaling into ±ū and s the effort knob. At a = 0 this is the ``joint-goal``
controller at gain s·joint_gain, which keeps the joint limits by construction (a straight joint path
inside a convex box); the network learns when and how far to cut across in task space (a₁..ₙ) and how
hard to pull towards the goal (a₀ ∈ [−1, 1]: no pull to twice the gain). The goal is the model's IK, not
learned. Features: the task-relative table, then

====================  ======  ==============================================================
feature               size    meaning
====================  ======  ==============================================================
d / (‖d‖ + 1 mrad)    m       direction to the goal in joint space, d = θ* − θ
log‖d‖                1       its magnitude, (log10(‖d‖ + 10⁻⁴ rad) + 2) / 2
room / π              1       the smallest distance of a joint to its limit, rad / π
====================  ======  ==============================================================

``"joint"`` (``FEATURE_VERSION`` 2 files): the table above this one, and the action map below.

Action (``"joint"``): the network's output ``a`` is clipped to [−1, 1] per joint and mapped to
``u = action_scale · action_fraction · a ⊙ ū`` (rad/s), ū the velocity limits, clipped to ±ū.
``action_fraction`` is fixed at training time; ``action_scale`` (default 1) is the
run-time effort knob. Scaling the output of a fixed feedback policy would also scale its
loop gain near the target, and a learned policy's gain there is high: at 1.6x it chatters.
So the knob is an input as well: training draws ``action_scale`` per episode, log-uniformly
from ``action_scale_range``, and the network sees ``ln(action_scale)``; it learns one policy
per effort level, fast and still stable at large scales, slow at small ones.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from snac_gym.model.joint_goal import TRACKING_ROOM, GoalArms
from snac_gym.model.kinematics import damped_resolve_rows
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import scale_rows_into_limits

#: Version of the feature definition above; stored in every policy file and checked on load:
#: 2 is the joint-space policy, 3 the task-relative one, 4 the goal-relative one.
FEATURE_VERSION = 3
#: The feature version of each kind of policy.
ACTION_KINDS = {"joint": 2, "task-relative": 3, "goal-relative": 4}
#: ε_v of the task-relative action (m): the feedback's floor, so an error of exactly zero is still corrected.
RELATIVE_ERROR_FLOOR = 1e-4
#: ε of the log-magnitude feature, m.
LOG_ERROR_FLOOR = 1e-4


@dataclass(frozen=True)
class FeatureSpec:
    """Scales of the features (see the module docstring) and of the action map.

    Attributes:
        error_scale_coarse: Error scale of the coarse error feature, m.
        error_scale_fine: Error scale of the squashed fine error feature, m.
        velocity_scale: Scale of the desired-velocity feature, m/s.
        position_centre: Centre of the end-effector position feature, m (base frame).
        position_scale: Scale of the end-effector position feature, m.
        action_fraction: Fraction of the velocity limits that ``a = ±1`` commands.
        action_scale_range: ``(low, high)`` of the per-episode ``action_scale`` drawn at
            training time (log-uniform); ``low == high`` trains at one scale.
        action: ``"joint"``, ``"task-relative"`` or ``"goal-relative"`` (the module docs).
        gain_max: Task- and goal-relative: the feedback gain ``a = ±1`` commands, 1/s.
        damping: Task- and goal-relative: λ of the damped pseudo-inverse, m.
        joint_gain: Goal-relative: the joint-space gain towards the goal at ``a₀ = 0``, 1/s.
        version: :data:`FEATURE_VERSION` of the definition these scales belong to.
    """

    error_scale_coarse: float = 0.1
    error_scale_fine: float = 0.01
    velocity_scale: float = 0.1
    position_centre: tuple[float, ...] = (-0.675, 0.15, 0.425)
    position_scale: float = 0.3
    action_fraction: float = 0.5
    action_scale_range: tuple[float, float] = (0.5, 4.0)
    action: str = "joint"
    gain_max: float = 4.0
    damping: float = 0.01
    joint_gain: float = 2.0
    version: int = field(default=-1)

    def __post_init__(self) -> None:
        if self.action not in ACTION_KINDS:
            raise ValueError(f"feature spec: action must be one of {sorted(ACTION_KINDS)}, got {self.action!r}")
        if self.version == -1:
            object.__setattr__(self, "version", ACTION_KINDS[self.action])
        for name in (
            "gain_max",
            "damping",
            "joint_gain",
            "error_scale_coarse",
            "error_scale_fine",
            "velocity_scale",
            "position_scale",
            "action_fraction",
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"feature spec: {name} must be a positive number, got {value!r}")
        object.__setattr__(self, "position_centre", tuple(float(v) for v in self.position_centre))
        low, high = (float(v) for v in self.action_scale_range)
        if not (np.isfinite(high) and 0 < low <= high):
            raise ValueError(
                f"feature spec: action_scale_range must be 0 < low <= high, got {self.action_scale_range!r}"
            )
        object.__setattr__(self, "action_scale_range", (low, high))

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (stored in configs and policy files)."""
        data = asdict(self)
        data["position_centre"] = list(self.position_centre)
        data["action_scale_range"] = list(self.action_scale_range)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "FeatureSpec":
        """Inverse of :meth:`to_dict`.

        Raises:
            ValueError: On unknown keys, bad values or a feature version this code does not compute.
        """
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"feature spec: unknown keys {sorted(unknown)}")
        # A spec that names no action has the kind of its version (version 2 files predate the
        # task-relative kind and are joint-space).
        data = dict(data)
        if "action" not in data and data.get("version") in ACTION_KINDS.values():
            data["action"] = next(kind for kind, version in ACTION_KINDS.items() if version == data["version"])
        if "version" in data and data["version"] not in ACTION_KINDS.values():
            raise ValueError(
                f"feature spec version {data['version']} is not one this snac-gym computes "
                f"({sorted(ACTION_KINDS.values())})"
            )
        spec = cls(**data)
        if spec.version != ACTION_KINDS[spec.action]:
            raise ValueError(
                f"feature spec version {spec.version} does not go with action {spec.action!r} "
                f"(version {ACTION_KINDS[spec.action]})"
            )
        return spec

    @property
    def task_relative(self) -> bool:
        """Whether the network's command goes through the model's J(θ) (task- or goal-relative: the module docs)."""
        return self.action in ("task-relative", "goal-relative")

    @property
    def goal_relative(self) -> bool:
        """Whether the policy also pulls towards an in-limit goal configuration (needs the goal's state)."""
        return self.action == "goal-relative"


def feature_size(layout: ObservationLayout, spec: FeatureSpec | None = None) -> int:
    """Number of features for ``layout``: 2m + 4n + 2 (joint), 4n + 1 (task-relative), 4n + m + 3 (goal-relative)."""
    if spec is not None and spec.goal_relative:
        return 4 * layout.task_dim + layout.n_joints + 3
    if spec is not None and spec.task_relative:
        return 4 * layout.task_dim + 1
    return 2 * layout.n_joints + 4 * layout.task_dim + 2


def action_size(layout: ObservationLayout, spec: FeatureSpec) -> int:
    """Size of the network's action: m joints, the task dimension n (task-relative) or n + 1 (goal-relative)."""
    if spec.goal_relative:
        return layout.task_dim + 1
    return layout.task_dim if spec.task_relative else layout.n_joints


@dataclass(frozen=True)
class GoalState:
    """What a goal-relative policy needs beyond the observation, one row per observation.

    Attributes:
        goal: θ*(t), ``(m,)`` or ``(B, m)`` (:class:`snac_gym.model.joint_goal.GoalArms`).
        velocity: θ̇*(t), the same shape.
        lower, upper: The joint position limits ``(m,)`` (for the room feature).
    """

    goal: np.ndarray
    velocity: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def row(self, index: int) -> "GoalState":
        """The state of one observation, from a batch's."""
        return GoalState(self.goal[index], self.velocity[index], self.lower, self.upper)


class EpisodeGoals:
    """The goal state of B goal-relative episodes, the same code at training and at run time.

    An episode's goal is solved from its first observation (θ₀, x_d(0)); every observation then advances
    its virtual arm one period (:class:`snac_gym.model.joint_goal.GoalArms`: a tracking episode's goal prefers
    :data:`~snac_gym.model.joint_goal.TRACKING_ROOM`).

    Args:
        kinematics: The model's position kinematics.
        velocity_limits: ū ``(m,)``.
        dt: Control period, s.
        tracking: Whether the reference moves.
        count: Number of episodes.
    """

    def __init__(self, kinematics: Any, velocity_limits: np.ndarray, dt: float, tracking: bool, count: int) -> None:
        self.arms = GoalArms(
            kinematics, velocity_limits, dt, preferred_margin=TRACKING_ROOM if tracking else 0.0, moving=tracking
        )
        self.arms.allocate(count)
        self.lower, self.upper = kinematics.lower_limits, kinematics.upper_limits
        self.pending = np.ones(count, dtype=bool)

    def restart(self, rows: Any = slice(None)) -> None:
        """The next observation of ``rows`` is an episode's first."""
        self.pending[rows] = True

    def observe(self, obs: np.ndarray, layout: ObservationLayout, rows: Any = slice(None)) -> GoalState:
        """The goal state for observations ``(B_rows, d)`` of ``rows``, advancing their virtual arms one period."""
        rows = np.arange(len(self.pending))[rows]
        s = layout.slices
        x_d = obs[:, s["x_d"]]
        first = self.pending[rows]
        if first.any():
            self.arms.start(obs[first][:, s["q"]], x_d[first], rows[first])
            self.pending[rows[first]] = False
        goal, velocity = self.arms.step(x_d, obs[:, s["xdot_d"]], rows)
        return GoalState(goal, velocity, self.lower, self.upper)


def _goal_features(q: np.ndarray, state: GoalState) -> np.ndarray:
    offset = np.asarray(state.goal, dtype=np.float64) - q
    norm = np.sqrt(np.sum(offset * offset, axis=-1, keepdims=True))
    room = np.min(np.minimum(q - state.lower, state.upper - q), axis=-1, keepdims=True)
    return np.concatenate((offset / (norm + 1e-3), (np.log10(norm + 1e-4) + 2.0) / 2.0, room / np.pi), axis=-1)


def observation_features(
    obs: np.ndarray,
    layout: ObservationLayout,
    spec: FeatureSpec,
    action_scale: float = 1.0,
    goal: GoalState | None = None,
) -> np.ndarray:
    """The network input for one observation ``(d,)`` or a batch ``(B, d)``, as float32.

    ``action_scale`` is the effort knob the command will be scaled with (the last feature of a joint
    policy); ``goal`` the goal-relative policy's goal state.

    Raises:
        ValueError: If the observations do not have the layout's size, or a goal-relative spec gets no goal.
    """
    obs = np.asarray(obs, dtype=np.float64)
    if obs.shape[-1:] != (layout.size,) or obs.ndim not in (1, 2):
        raise ValueError(f"observation must have shape ({layout.size},) or (B, {layout.size}), got {obs.shape}")
    s = layout.slices
    q = obs[..., s["q"]]
    e = obs[..., s["e"]]
    error_norm = np.sqrt(np.sum(e * e, axis=-1, keepdims=True))
    if spec.task_relative:
        xdot_d = obs[..., s["xdot_d"]]
        parts: list[np.ndarray] | tuple[np.ndarray, ...]  # a list here, a tuple below
        parts = [
            e / np.maximum(error_norm, 1e-12),
            (np.log10(error_norm + 1e-5) + 2.5) / 1.5,
            xdot_d / spec.velocity_scale,
            xdot_d / (error_norm + 1e-3) / 10.0,
            e / (2.0 * spec.error_scale_coarse),
        ]
        if spec.goal_relative:
            if goal is None:
                raise ValueError("a goal-relative PPO policy needs its goal state (goal=)")
            parts.append(_goal_features(q, goal))
        return np.concatenate(parts, axis=-1).astype(np.float32)
    centre = np.asarray(spec.position_centre, dtype=np.float64)
    if centre.shape != (layout.task_dim,):
        raise ValueError(f"feature spec: position_centre needs {layout.task_dim} values, got {centre.shape}")
    parts = (
        np.sin(q),
        np.cos(q),
        e / spec.error_scale_coarse,
        np.tanh(e / spec.error_scale_fine),
        np.log10(error_norm + LOG_ERROR_FLOOR),
        obs[..., s["xdot_d"]] / spec.velocity_scale,
        (obs[..., s["x"]] - centre) / spec.position_scale,
        np.full(error_norm.shape, np.log(float(action_scale))),
    )
    return np.concatenate(parts, axis=-1).astype(np.float32)


def task_velocity(
    action: np.ndarray, obs: np.ndarray, layout: ObservationLayout, spec: FeatureSpec, action_scale: Any = 1.0
) -> np.ndarray:
    """The task-relative action's end-effector velocity ``v = ẋ_d + s·gain_max·(‖e‖ + ε_v)·clip(a)``.

    ``action_scale`` is a number or one per row ``(B, 1)``.
    """
    s = layout.slices
    obs = np.asarray(obs, dtype=np.float64)
    e = obs[..., s["e"]]
    error_norm = np.sqrt(np.sum(e * e, axis=-1, keepdims=True))
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    gain = np.asarray(action_scale, dtype=np.float64) * spec.gain_max
    return obs[..., s["xdot_d"]] + gain * (error_norm + RELATIVE_ERROR_FLOOR) * action


def _resolve(jacobians: np.ndarray, velocity: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """``Jᵀ(JJᵀ + λ²I)⁻¹ v`` for one ``J`` ``(n, m)`` and ``v`` ``(n,)``, or stacks ``(B, n, m)``, ``(B, n)``."""
    return damped_resolve_rows(jacobians, velocity, spec.damping)


def task_relative_command(
    action: np.ndarray,
    obs: np.ndarray,
    layout: ObservationLayout,
    jacobians: np.ndarray,
    velocity_limits: np.ndarray,
    spec: FeatureSpec,
    action_scale: Any = 1.0,
) -> np.ndarray:
    """Joint velocities (rad/s) of task-relative actions ``(n,)`` or ``(B, n)``: ``Jᵀ(JJᵀ + λ²I)⁻¹ v``, clipped to ±ū.

    ``jacobians`` is ``J(θ)`` ``(n, m)`` or one per row ``(B, n, m)``.
    """
    command = _resolve(jacobians, task_velocity(action, obs, layout, spec, action_scale), spec)
    limits = np.asarray(velocity_limits, dtype=np.float64)
    return np.minimum(np.maximum(command, -limits), limits)


def goal_relative_command(
    action: np.ndarray,
    obs: np.ndarray,
    layout: ObservationLayout,
    jacobians: np.ndarray,
    velocity_limits: np.ndarray,
    spec: FeatureSpec,
    goal: GoalState,
    action_scale: Any = 1.0,
) -> np.ndarray:
    """Joint velocities (rad/s) of goal-relative actions ``(n + 1,)`` or ``(B, n + 1)`` (the module docs).

    ``u = sat(θ̇* + s·joint_gain·(1 + a₀)(θ* − θ) + Jᵀ(JJᵀ + λ²I)⁻¹ s·gain_max·(‖e‖ + ε_v)·a₁..ₙ)``, ``sat`` the
    uniform scaling into ±ū, so a = 0 is the ``joint-goal`` controller.
    """
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    obs = np.asarray(obs, dtype=np.float64)
    s = layout.slices
    e = obs[..., s["e"]]
    error_norm = np.sqrt(np.sum(e * e, axis=-1, keepdims=True))
    scale = np.asarray(action_scale, dtype=np.float64)
    velocity = scale * spec.gain_max * (error_norm + RELATIVE_ERROR_FLOOR) * action[..., 1:]
    task = _resolve(jacobians, velocity, spec)
    pull = scale * spec.joint_gain * (1.0 + action[..., :1])
    command = np.asarray(goal.velocity, dtype=np.float64) + pull * (goal.goal - obs[..., s["q"]]) + task
    return scale_rows_into_limits(command, np.asarray(velocity_limits, dtype=np.float64))


def command(
    action: np.ndarray,
    obs: np.ndarray,
    layout: ObservationLayout,
    velocity_limits: np.ndarray,
    spec: FeatureSpec,
    action_scale: float = 1.0,
    jacobians: np.ndarray | None = None,
    goal: GoalState | None = None,
) -> np.ndarray:
    """Joint velocities (rad/s) of the network's actions for observations ``(d,)`` or ``(B, d)``, any kind.

    A task- or goal-relative spec also needs ``J(θ)`` of each observation (``(n, m)`` or ``(B, n, m)``); a
    goal-relative one its goal state.

    Raises:
        ValueError: If a task-relative spec is given no Jacobians, or a goal-relative one no goal.
    """
    if not spec.task_relative:
        return action_to_command(action, velocity_limits, spec, action_scale)
    if jacobians is None:
        raise ValueError("a task-relative PPO policy needs J(θ) of each observation (jacobians=)")
    if spec.goal_relative:
        if goal is None:
            raise ValueError("a goal-relative PPO policy needs its goal state (goal=)")
        return goal_relative_command(action, obs, layout, jacobians, velocity_limits, spec, goal, action_scale)
    return task_relative_command(action, obs, layout, jacobians, velocity_limits, spec, action_scale)


def action_to_command(
    action: np.ndarray, velocity_limits: np.ndarray, spec: FeatureSpec, action_scale: float = 1.0
) -> np.ndarray:
    """Joint velocities (rad/s, float64) for normalised joint-space actions ``(m,)`` or ``(B, m)``.

    ``u = action_scale · action_fraction · clip(a, −1, 1) ⊙ ū``, clipped to ``±ū`` (which only
    matters when ``action_scale · action_fraction > 1``).
    """
    if spec.task_relative:
        raise ValueError("a task-relative action needs the observation and J(θ): use task_relative_command")
    limits = np.asarray(velocity_limits, dtype=np.float64)
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    command = action * (limits * (spec.action_fraction * float(action_scale)))
    return np.minimum(np.maximum(command, -limits), limits)
