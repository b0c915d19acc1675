"""The compiled command extremes (snac_gym/kernels/metrics.py) against the NumPy expressions they
replaced, bit for bit: peaks with ties (the first step wins, as np.argmax), commands at a limit,
one step, one joint."""

import numpy as np
import pytest

from snac_gym.kernels.metrics import command_extremes, reverse_sum_extremes
from snac_gym.rollout.kinematic import _swap_leading_axes


def _numpy_extremes(commands, limits, at_limit, dt):
    fractions = (np.abs(commands) / limits).max(axis=-1)
    peak_step = np.argmax(fractions, axis=1)
    magnitudes = np.abs(commands)
    peak_abs = magnitudes.max(axis=-1)
    peak_abs_step = np.argmax(peak_abs, axis=1)
    differences = np.empty_like(commands)
    np.subtract(commands[:, 1:], commands[:, :-1], out=differences[:, 1:])
    differences[:, 0] = commands[:, 0]
    rows = np.arange(len(commands))
    return (
        fractions[rows, peak_step], peak_step, peak_abs[rows, peak_abs_step], peak_abs_step,
        np.abs(differences / dt).max(axis=(1, 2)), (magnitudes >= at_limit).any(axis=-1).sum(axis=1),
    )  # fmt: skip


def _commands(rng, count, steps, m, limits):
    commands = rng.uniform(-1.2, 1.2, (count, steps, m)) * limits
    commands = np.clip(commands, -limits, limits)  # many entries exactly at a limit
    commands[0] = 0.0  # a rollout at rest throughout: every step ties at 0
    if steps > 3:
        commands[1, 3] = commands[1, 1]  # the same peak at two steps
        commands[1, 1, 0] = commands[1, 3, 0] = 5 * limits[0]
    return commands


@pytest.mark.parametrize("seed, count, steps, m", [(0, 7, 50, 6), (1, 3, 1, 6), (2, 4, 9, 1), (3, 5, 300, 7)])
def test_command_extremes_are_the_numpy_expressions_bit_for_bit(seed, count, steps, m):
    rng = np.random.default_rng(seed)
    limits = rng.uniform(0.5, 3.0, m)
    at_limit = limits * (1.0 - 1e-9)
    commands = _commands(rng, count, steps, m, limits)
    dt = 1 / 125
    compiled = command_extremes(commands, limits, at_limit, dt)
    for got, expected in zip(compiled, _numpy_extremes(commands, limits, at_limit, dt), strict=True):
        np.testing.assert_array_equal(got, expected)
    if steps > 3:
        assert compiled[1][1] == 1 and compiled[3][1] == 1  # the first of two equal peaks
    assert compiled[1][0] == 0 and compiled[0][0] == 0.0  # at rest: step 0, peak 0


def test_a_nan_or_an_inf_command_gives_numpys_figures():
    """Not what the evaluator's engines let through (they refuse a non-finite command), but what a caller
    of rollout_metrics with other rollouts gets: NaN as NumPy's maximum gives it, never a finite peak."""
    rng = np.random.default_rng(5)
    limits = np.full(6, 2.0)
    commands = rng.uniform(-1.0, 1.0, (4, 20, 6))
    commands[0, 7, 2] = np.nan
    commands[1, 3, 5] = np.inf
    commands[2, 0, 0] = commands[2, 11, 4] = np.nan  # two NaNs: the first is the peak's step
    compiled = command_extremes(commands, limits, limits * (1.0 - 1e-9), 0.008)
    for got, expected in zip(compiled, _numpy_extremes(commands, limits, limits * (1.0 - 1e-9), 0.008), strict=True):
        np.testing.assert_array_equal(got, expected)
    assert np.isnan(compiled[0][[0, 2]]).all() and compiled[1][0] == 7 and compiled[1][2] == 0
    sums = np.cumsum(commands[:, ::-1], axis=1)
    largest, smallest = reverse_sum_extremes(commands)
    np.testing.assert_array_equal(largest, sums.max(axis=1))
    np.testing.assert_array_equal(smallest, sums.min(axis=1))


@pytest.mark.parametrize("seed, count, steps, m", [(0, 6, 80, 6), (1, 2, 1, 6), (2, 3, 2, 7)])
def test_reverse_sum_extremes_are_those_of_numpys_cumsum(seed, count, steps, m):
    commands = np.random.default_rng(seed).normal(size=(count, steps, m))
    sums = np.cumsum(commands[:, ::-1], axis=1)
    largest, smallest = reverse_sum_extremes(commands)
    np.testing.assert_array_equal(largest, sums.max(axis=1))
    np.testing.assert_array_equal(smallest, sums.min(axis=1))


def test_sample_major_is_the_transposed_log():
    log = np.random.default_rng(4).normal(size=(11, 5, 6))
    moved = _swap_leading_axes(log)
    assert moved.flags.c_contiguous and moved.shape == (5, 11, 6)
    np.testing.assert_array_equal(moved, log.transpose(1, 0, 2))
