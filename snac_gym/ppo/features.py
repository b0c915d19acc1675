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

Action: the network's output ``a`` is clipped to [−1, 1] per joint and mapped to
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

from snac_gym.observation import ObservationLayout

#: Version of the feature definition above; stored in every policy file and checked on load.
FEATURE_VERSION = 2
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
        version: :data:`FEATURE_VERSION` of the definition these scales belong to.
    """

    error_scale_coarse: float = 0.1
    error_scale_fine: float = 0.01
    velocity_scale: float = 0.1
    position_centre: tuple[float, ...] = (-0.675, 0.15, 0.425)
    position_scale: float = 0.3
    action_fraction: float = 0.5
    action_scale_range: tuple[float, float] = (0.5, 4.0)
    version: int = field(default=FEATURE_VERSION)

    def __post_init__(self) -> None:
        for name in ("error_scale_coarse", "error_scale_fine", "velocity_scale", "position_scale", "action_fraction"):
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
        spec = cls(**data)
        if spec.version != FEATURE_VERSION:
            raise ValueError(
                f"feature spec version {spec.version} is not the version this snac-gym computes ({FEATURE_VERSION})"
            )
        return spec


def feature_size(layout: ObservationLayout) -> int:
    """Number of features for ``layout`` (2m + 4n + 2)."""
    return 2 * layout.n_joints + 4 * layout.task_dim + 2


def observation_features(
    obs: np.ndarray, layout: ObservationLayout, spec: FeatureSpec, action_scale: float = 1.0
) -> np.ndarray:
    """The network input for one observation ``(d,)`` or a batch ``(B, d)``, as float32.

    ``action_scale`` is the effort knob the command will be scaled with (the last feature).

    Raises:
        ValueError: If the observations do not have the layout's size.
    """
    obs = np.asarray(obs, dtype=np.float64)
    if obs.shape[-1:] != (layout.size,) or obs.ndim not in (1, 2):
        raise ValueError(f"observation must have shape ({layout.size},) or (B, {layout.size}), got {obs.shape}")
    s = layout.slices
    q = obs[..., s["q"]]
    e = obs[..., s["e"]]
    error_norm = np.sqrt(np.sum(e * e, axis=-1, keepdims=True))
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


def action_to_command(
    action: np.ndarray, velocity_limits: np.ndarray, spec: FeatureSpec, action_scale: float = 1.0
) -> np.ndarray:
    """Joint velocities (rad/s, float64) for normalised actions ``(m,)`` or ``(B, m)``.

    ``u = action_scale · action_fraction · clip(a, −1, 1) ⊙ ū``, clipped to ``±ū`` (which only
    matters when ``action_scale · action_fraction > 1``).
    """
    limits = np.asarray(velocity_limits, dtype=np.float64)
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    command = action * (limits * (spec.action_fraction * float(action_scale)))
    return np.minimum(np.maximum(command, -limits), limits)
