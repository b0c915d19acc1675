"""The references of many samples evaluated at every control step at once.

The kinematic backend steps hundreds of samples in lockstep; calling
``reference.position_and_velocity(t)`` per sample and step would cost more than the rest of
the step. This evaluates the same formulas of :mod:`snac_gym.references` on arrays
(tests/test_evaluation_backends.py checks it against the per-call methods):

* :class:`~snac_gym.references.FixedTarget`: ``x_d = target``, ``ẋ_d = 0``;
* :class:`~snac_gym.references.Ellipse`: ``x_d = c + cos(ωt + φ) a R ê₁ + sin(ωt + φ) b R ê₂``,
  ``ẋ_d = ω (cos(ωt + φ) b R ê₂ − sin(ωt + φ) a R ê₁)``, R from the plane's roll-pitch-yaw
  (:func:`~snac_gym.references.rotation_from_rpy`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from snac_gym.references import Ellipse, FixedTarget, rotation_from_rpy


def reference_trajectories(
    references: Sequence[FixedTarget | Ellipse], times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x_d`` and ``ẋ_d`` of every reference at every time, and each reference's centre.

    Args:
        references: B references of one kind or mixed.
        times: ``(K,)`` times, s.

    Returns:
        ``(x_d, xdot_d, centres)`` of shapes ``(B, K, 3)``, ``(B, K, 3)`` and ``(B, 3)``.
    """
    times = np.asarray(times, dtype=float)
    count, steps = len(references), len(times)
    positions = np.empty((count, steps, 3))
    velocities = np.zeros((count, steps, 3))
    centres = np.empty((count, 3))
    for i, reference in enumerate(references):
        centres[i] = reference.centre
        if isinstance(reference, FixedTarget):
            positions[i] = reference.target
            continue
        if not isinstance(reference, Ellipse):
            raise TypeError(f"reference {i} is a {type(reference).__name__}, not a FixedTarget or Ellipse")
        rotation = rotation_from_rpy(*reference.orientation)
        major = rotation[:, 0] * reference.semi_axes[0]
        minor = rotation[:, 1] * reference.semi_axes[1]
        angles = reference.angular_speed * times + reference.phase
        cos, sin = np.cos(angles)[:, None], np.sin(angles)[:, None]
        positions[i] = reference.centre + cos * major + sin * minor
        velocities[i] = reference.angular_speed * (cos * minor - sin * major)
    return positions, velocities, centres
