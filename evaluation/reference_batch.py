"""The references of many samples evaluated at every control step at once.

The kinematic backend steps hundreds of samples in lockstep; calling
``reference.position_and_velocity(t)`` per sample and step would cost more than the rest of
the step. This stacks each reference's vectorised ``trajectory(times)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from snac_gym.references import Ellipse, FixedTarget


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
    velocities = np.empty((count, steps, 3))
    centres = np.empty((count, 3))
    for i, reference in enumerate(references):
        if not isinstance(reference, (FixedTarget, Ellipse)):
            raise TypeError(f"reference {i} is a {type(reference).__name__}, not a FixedTarget or Ellipse")
        centres[i] = reference.centre
        positions[i], velocities[i] = reference.trajectory(times)
    return positions, velocities, centres
