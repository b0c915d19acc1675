"""The references of a vector env's N episodes as arrays, evaluated for all at once each step.

Part of the batched vector env (:mod:`snac_gym.envs.vector`): the single env asks its one reference per step, N
episodes would make N Python calls; stacked, the ellipses are one NumPy expression.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from snac_gym.references import Ellipse, FixedTarget, Reference

__all__ = ["ReferenceBatch"]


class ReferenceBatch:
    """The references of N episodes as arrays, evaluated for all at once each step.

    Fixed targets are their centre with ẋ_d = 0; ellipses are stacked as centre, scaled axes,
    ω and φ and evaluated with the formula of :meth:`Ellipse.position_and_velocity`; any other
    reference type (a task registered later) is asked per episode.

    Args:
        count: Number of episodes N.
        dim: Task dimension n.
    """

    def __init__(self, count: int, dim: int = 3) -> None:
        self.centre = np.zeros((count, dim))
        self._major = np.zeros((count, dim))
        self._minor = np.zeros((count, dim))
        self._speed = np.zeros(count)
        self._phase = np.zeros(count)
        self._ellipse = np.zeros(count, dtype=bool)
        self._other: dict[int, Reference] = {}
        self.references: list[Reference | None] = [None] * count

    def set(self, index: int, reference: Reference) -> None:
        """Make ``reference`` episode ``index``'s."""
        self.references[index] = reference
        self._other.pop(index, None)
        self._ellipse[index] = isinstance(reference, Ellipse)
        self.centre[index] = reference.centre
        if isinstance(reference, Ellipse):
            self._major[index] = reference._major
            self._minor[index] = reference._minor
            self._speed[index], self._phase[index] = reference.angular_speed, reference.phase
        elif not isinstance(reference, FixedTarget):
            self._other[index] = reference

    def evaluate(self, times: np.ndarray, rows: Any = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """``(x_d, ẋ_d)`` of the episodes ``rows`` at their times ``times``, each ``(len(times), n)``."""
        centre = self.centre[rows]
        x_d, xdot_d = centre.copy(), np.zeros_like(centre)
        ellipse = self._ellipse[rows]
        if ellipse.any():
            picked = slice(None) if ellipse.all() else np.flatnonzero(ellipse)
            speed, phase = self._speed[rows][picked], self._phase[rows][picked]
            major, minor = self._major[rows][picked], self._minor[rows][picked]
            angle = speed * times[picked] + phase
            cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
            x_d[picked] = centre[picked] + cos * major + sin * minor
            xdot_d[picked] = (speed[:, None] * cos) * minor - (speed[:, None] * sin) * major
        if self._other:
            indices = np.arange(len(self.centre))[rows]
            for row, index in enumerate(indices):
                if int(index) in self._other:
                    x_d[row], xdot_d[row] = self._other[int(index)].position_and_velocity(float(times[row]))
        return x_d, xdot_d
