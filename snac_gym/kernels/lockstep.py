"""Compiled steps of the lockstep rollout (:func:`snac_gym.rollout.simulate_kinematic`): every sample's observation
in one pass, and the commands clipped into the velocity limits and checked in another.

They replace a dozen NumPy calls a control step (eight field copies, a finiteness test and a reduction, two clips, a
copy into the log), each of which costs about a microsecond whatever its size: 15 µs a step on the evaluator's 250
samples, against 6 µs (``python docs/scripts/lockstep_step_cost.py``). They copy, compare and select only, so their
results are the NumPy loop's bit for bit.
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import kernel, read_only
from snac_gym.kernels.small import clip_into


def _observation_example() -> tuple[np.ndarray, ...]:
    """The engine's arrays: its own (writeable) but for the kinematics' remembered positions, which are read-only."""
    rows = np.ones((1, 3))
    return np.ones((1, 6)), np.ones((1, 6)), read_only(np.ones((1, 3))), rows, rows, rows, rows


@kernel(_observation_example)
def observations(
    q: np.ndarray,
    qdot: np.ndarray,
    x: np.ndarray,
    x_d: np.ndarray,
    xdot_d: np.ndarray,
    error: np.ndarray,
    centres: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """A new ``(B, 2m + 5n)`` array of the rows ``[θ, θ̇, x, x_d, ẋ_d, e, x_c]``: the fields of
    :class:`~snac_gym.observation.ObservationLayout` in its order, from ``(B, m)`` and ``(B, n)`` arrays."""
    count, m, n = q.shape[0], q.shape[1], x.shape[1]
    obs = np.empty((count, 2 * m + 5 * n))
    for b in range(count):
        for j in range(m):
            obs[b, j] = q[b, j]
            obs[b, m + j] = qdot[b, j]
        start = 2 * m
        for i in range(n):
            obs[b, start + i] = x[b, i]
            obs[b, start + n + i] = x_d[b, i]
            obs[b, start + 2 * n + i] = xdot_d[b, i]
            obs[b, start + 3 * n + i] = error[b, i]
            obs[b, start + 4 * n + i] = centres[b, i]
    return obs


@kernel(lambda: (read_only(np.ones((1, 6))), read_only(np.ones(6)), np.ones((1, 6))))
def hold_commands(commands: np.ndarray, limits: np.ndarray, held: np.ndarray) -> bool:  # pragma: no cover - compiled
    """``held`` ← ``np.minimum(np.maximum(commands, −limits), limits)`` for ``(B, m)`` commands and ``(m,)`` limits
    (a NaN stays NaN, as there); returns whether every command was finite."""
    finite = True
    for b in range(commands.shape[0]):
        for j in range(commands.shape[1]):
            if not np.isfinite(commands[b, j]):
                finite = False
            held[b, j] = clip_into(commands[b, j], limits[j])
    return finite
