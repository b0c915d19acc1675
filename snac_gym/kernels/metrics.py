"""Compiled per-rollout extremes of the commands, for :func:`~snac_gym.metrics.rollout_metrics`.

The evaluator measures every rollout of a ``(B, K, m)`` command array by peaks (of ``|uₖⱼ|/ūⱼ``, of
``‖uₖ‖∞``, of ``|u̇ₖⱼ|``), a count of steps at a limit, and the extremes of the joint angles rebuilt
backwards from θ_K. As NumPy operations that was a dozen passes over the array, most of them
reductions over its last axis of m = 6 or 7 values, where NumPy's per-row overhead dominates: more
time than the rollout's cost itself. Here each is one pass. Every figure is a maximum, a minimum, a
count or a sequential running sum, computed with the same floating-point operations as the NumPy
expressions, so the results are the same bit for bit (``tests/kernels/test_metrics_kernel.py``), a NaN
included: as in NumPy, a maximum or minimum over values with a NaN is NaN, and a NaN is the peak.
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, helper, kernel


@helper
def _above(value: float, best: float) -> bool:  # pragma: no cover - compiled
    """Whether ``value`` replaces ``best`` as a running maximum, NumPy's way: a NaN wins and then stays."""
    return value > best or (value != value and best == best)


def _examples() -> Example:
    return (np.ones((1, 2, 6)), np.ones(6), np.ones(6), 0.01)


@helper
def _rollout_extremes(
    commands: np.ndarray, b: int, limits: np.ndarray, at_limit: np.ndarray, dt: float, nan_aware: bool
) -> tuple[float, int, float, int, float, int, bool]:  # pragma: no cover - compiled
    """:func:`command_extremes` of rollout ``b``, and whether a NaN came up. Without ``nan_aware`` the
    maxima are plain ones, which skip a NaN; the caller then computes the rollout again with it."""
    steps, m = commands.shape[1], commands.shape[2]
    best, best_step, best_abs, best_abs_step, rate, at, nan = -1.0, 0, -1.0, 0, 0.0, 0, False
    for k in range(steps):
        fraction, largest, reached = -1.0, -1.0, False
        for j in range(m):
            u = commands[b, k, j]
            magnitude = abs(u)
            ratio = magnitude / limits[j]
            change = abs((u - commands[b, k - 1, j]) / dt) if k > 0 else abs(u / dt)
            reached = reached or magnitude >= at_limit[j]
            if nan_aware:
                if _above(ratio, fraction):
                    fraction = ratio
                if _above(magnitude, largest):
                    largest = magnitude
                if _above(change, rate):
                    rate = change
            else:
                fraction, largest, rate = max(fraction, ratio), max(largest, magnitude), max(rate, change)
                nan |= (ratio != ratio) | (change != change)
        if _above(fraction, best):  # strictly above: the first step of the peak, as np.argmax
            best, best_step = fraction, k
        if _above(largest, best_abs):
            best_abs, best_abs_step = largest, k
        at += reached
    return best, best_step, best_abs, best_abs_step, rate, at, nan


@kernel(_examples)
def command_extremes(
    commands: np.ndarray, limits: np.ndarray, at_limit: np.ndarray, dt: float
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]:  # pragma: no cover - compiled; tested against NumPy
    """Per rollout of ``commands`` ``(B, K, m)``, K ≥ 1:

    ``(peak, peak_step, peak_abs, peak_abs_step, max_abs_rate, steps_at_limit)``: the largest
    ``max_j |uₖⱼ|/ūⱼ`` (``limits`` = ū) and the first step k where it occurs; the largest
    ``‖uₖ‖∞`` and its first step; the largest ``|(uₖⱼ − uₖ₋₁ⱼ)/Δt|`` with u₋₁ = 0; and the number of
    steps with some ``|uₖⱼ| ≥ at_limit[j]``.
    """
    count = commands.shape[0]
    peak = np.empty(count)
    peak_step = np.empty(count, dtype=np.int64)
    peak_abs = np.empty(count)
    peak_abs_step = np.empty(count, dtype=np.int64)
    max_abs_rate = np.empty(count)
    steps_at_limit = np.empty(count, dtype=np.int64)
    for b in range(count):
        figures = _rollout_extremes(commands, b, limits, at_limit, dt, False)
        if figures[6]:  # a NaN: NumPy's maxima return it, and its first step
            figures = _rollout_extremes(commands, b, limits, at_limit, dt, True)
        peak[b], peak_step[b], peak_abs[b], peak_abs_step[b], max_abs_rate[b], steps_at_limit[b] = figures[:6]
    return peak, peak_step, peak_abs, peak_abs_step, max_abs_rate, steps_at_limit


@kernel(lambda: (np.ones((1, 2, 6)),))
def reverse_sum_extremes(
    commands: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against NumPy
    """Per rollout and joint of ``commands`` ``(B, K, m)``: the largest and the smallest of the sums
    ``Σ_{i≥k} uᵢⱼ`` over k, each summed from i = K−1 down, as ``np.cumsum(commands[:, ::-1], axis=1)``."""
    count, steps, m = commands.shape
    largest = np.empty((count, m))
    smallest = np.empty((count, m))
    for b in range(count):
        for j in range(m):
            total = commands[b, steps - 1, j]
            high, low = total, total
            for k in range(steps - 2, -1, -1):
                total += commands[b, k, j]
                high, low = max(high, total), min(low, total)
            if total != total:  # a sum turned NaN stays NaN to the last one: NumPy's extremes are NaN
                high = low = total
            largest[b, j], smallest[b, j] = high, low
    return largest, smallest
