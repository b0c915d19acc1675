"""The compiled scaling into the velocity limits (snac_gym/kernels/small.py::scale_rows, behind
snac_gym.policies.base.scale_rows_into_limits) against the NumPy expression it replaced, bit for bit: rows inside,
at and beyond the limits, ties, NaN and infinities, signed zeros, one row and a stack, views and other dtypes."""

import numpy as np
import pytest

from snac_gym.policies.base import scale_rows_into_limits


def _numpy(commands, limits):
    with np.errstate(all="ignore"):  # inf/inf and NaN rows warn in NumPy; the kernel says nothing
        return _expression(commands, limits)


def _expression(commands, limits):
    scales = np.max(np.abs(commands) / limits, axis=-1, keepdims=True)
    scaled = commands / np.maximum(scales, 1.0)
    return np.minimum(np.maximum(scaled, -limits), limits)


def _same_bits(actual, expected):
    assert actual.shape == expected.shape and actual.dtype == expected.dtype
    # NaN payloads aside, every value and the sign of every zero
    nan = np.isnan(expected)
    assert np.array_equal(np.isnan(actual), nan)
    assert np.array_equal(actual[~nan].view(np.int64), expected[~nan].view(np.int64))


def _rows(rng, count, limits):
    m = len(limits)
    rows = rng.uniform(-3.0, 3.0, (count, m)) * limits  # a third inside, most beyond
    rows[0] = 0.0
    rows[1] = -0.0  # signed zeros kept
    rows[2] = limits  # exactly at the limits: a scale of 1, a tie on every joint
    rows[3] = -2.0 * limits  # every joint ties at the largest ratio
    rows[4, 0] = np.nan
    rows[5, -1] = np.inf
    rows[6, 0], rows[6, -1] = -np.inf, np.inf
    rows[7] = rng.uniform(-1.0, 1.0, m) * 1e300  # ratios near overflow
    rows[8] = rng.uniform(-1.0, 1.0, m) * 1e-300  # subnormal quotients
    rows[9, 0] = np.nan
    rows[9, -1] = np.inf  # NaN and infinity in one row (the same entry with one joint)
    return rows


@pytest.mark.parametrize("seed, count, m", [(0, 250, 6), (1, 12, 7), (2, 10, 1), (3, 40, 3)])
def test_the_compiled_scaling_is_numpys_bit_for_bit(seed, count, m):
    rng = np.random.default_rng(seed)
    limits = rng.uniform(0.5, 3.2, m)
    rows = _rows(rng, count, limits)
    _same_bits(scale_rows_into_limits(rows, limits), _numpy(rows, limits))
    for row in rows:  # one row alone: bit for bit the row of the stack
        _same_bits(scale_rows_into_limits(row, limits), _numpy(row, limits))
    view = np.asfortranarray(rows)[::2]  # not C-contiguous
    _same_bits(scale_rows_into_limits(view, limits), _numpy(view, limits))
    frozen = rows.copy()
    frozen.setflags(write=False)
    _same_bits(scale_rows_into_limits(frozen, limits), _numpy(frozen, limits))
    with np.errstate(over="ignore"):  # 1e300 is inf in float32
        single = rows.astype(np.float32)  # promoted to float64 by the limits, as NumPy does
    _same_bits(scale_rows_into_limits(single, limits), _numpy(single, limits))
    whole = np.round(rows[10:] * 3).astype(np.int64)
    _same_bits(scale_rows_into_limits(whole, limits), _numpy(whole, limits))


def test_the_cases_left_to_numpy_give_numpys_result():
    """float32 commands with float32 limits stay float32; limits of another shape broadcast as NumPy does."""
    rng = np.random.default_rng(4)
    rows = rng.uniform(-3.0, 3.0, (20, 6)).astype(np.float32)
    limits = np.full(6, 1.5, dtype=np.float32)
    _same_bits(scale_rows_into_limits(rows, limits), _numpy(rows, limits))
    _same_bits(scale_rows_into_limits(rows, np.float64(1.5)), _numpy(rows, np.float64(1.5)))
    stack = rng.uniform(-3.0, 3.0, (2, 5, 6))
    _same_bits(scale_rows_into_limits(stack, np.full(6, 1.5)), _numpy(stack, np.full(6, 1.5)))
    with pytest.raises(ValueError):
        scale_rows_into_limits(np.empty((3, 0)), np.empty(0))  # no joints: NumPy's own error


def test_the_input_is_left_as_it_was():
    rows = np.random.default_rng(5).uniform(-3.0, 3.0, (8, 6))
    kept = rows.copy()
    scale_rows_into_limits(rows, np.full(6, 1.0))
    assert np.array_equal(rows, kept)
