"""The lockstep rollout's compiled steps (snac_gym/kernels/lockstep.py) against the NumPy they replaced, bit for bit:
the observation built field by field with the layout's slices, and the clip into the velocity limits with its
finiteness test; and the engine's choice between the compiled observation and the slices."""

import numpy as np
import pytest

from snac_gym.kernels.compiled import read_only_view
from snac_gym.kernels.lockstep import hold_commands, observations
from snac_gym.observation import ObservationLayout
from snac_gym.rollout.kinematic import _observer


def _fields(rng, count, m, n):
    q, qdot = rng.normal(size=(count, m)), rng.normal(size=(count, m))
    x = read_only_view(rng.normal(size=(count, n)))
    x_d, xdot_d, centres = rng.normal(size=(count, n)), rng.normal(size=(count, n)), rng.normal(size=(count, n))
    error = np.subtract(x, x_d)
    q[0, 0], qdot[0, -1], centres[-1, 0] = -0.0, np.nan, np.inf  # copied as they are
    return q, qdot, x, x_d, xdot_d, error, centres


def _by_slices(layout, values):
    obs = np.empty((len(values[0]), layout.size))
    for name, value in zip(layout.FIELDS, values, strict=True):
        obs[:, layout.slices[name]] = value
    return obs


def _same_bits(actual, expected):
    assert actual.shape == expected.shape and actual.dtype == expected.dtype
    assert actual.tobytes() == expected.tobytes()


@pytest.mark.parametrize("count, m, n", [(250, 6, 3), (1, 7, 3), (5, 6, 6), (3, 1, 1)])
def test_the_compiled_observation_is_the_layouts_fields_bit_for_bit(count, m, n):
    layout = ObservationLayout(m, n)
    values = _fields(np.random.default_rng(count + m + n), count, m, n)
    expected = _by_slices(layout, values)
    _same_bits(observations(*values), expected)
    observe = _observer(layout, m, n)
    assert observe is observations
    _same_bits(observe(*values), expected)


def test_another_layout_gets_the_fields_where_its_slices_say():
    """A layout whose fields are elsewhere (here, the error first) is filled by its slices, not by the compiled
    standard order."""

    class ErrorFirst(ObservationLayout):
        def __init__(self, m, n):
            super().__init__(m, n)
            order = ("e", "q", "qdot", "x", "x_d", "xdot_d", "x_c")
            sizes = {"q": m, "qdot": m, "x": n, "x_d": n, "xdot_d": n, "e": n, "x_c": n}
            start = 0
            for name in order:
                self.slices[name] = slice(start, start + sizes[name])
                start += sizes[name]

    layout = ErrorFirst(6, 3)
    observe = _observer(layout, 6, 3)
    assert observe is not observations
    values = _fields(np.random.default_rng(1), 4, 6, 3)
    obs = observe(*values)
    _same_bits(obs, _by_slices(layout, values))
    np.testing.assert_array_equal(obs[:, :3], values[5])  # the error, where this layout keeps it


@pytest.mark.parametrize("count, m", [(250, 6), (1, 7), (4, 1)])
def test_the_compiled_clip_is_numpys_bit_for_bit_and_reports_non_finite_commands(count, m):
    rng = np.random.default_rng(count * m)
    limits = read_only_view(rng.uniform(0.5, 3.0, m))
    commands = rng.uniform(-2.0, 2.0, (count, m)) * limits
    commands[0, 0] = -0.0
    commands[-1, -1] = limits[-1]  # at a limit exactly
    held = np.empty((count, m))
    assert hold_commands(read_only_view(commands), limits, held)
    _same_bits(held, np.minimum(np.maximum(commands, -limits), limits))
    for bad in (np.nan, np.inf, -np.inf):
        broken = commands.copy()
        broken[count // 2, m // 2] = bad
        assert not hold_commands(read_only_view(broken), limits, held)
        _same_bits(held, np.minimum(np.maximum(broken, -limits), limits))  # NaN kept, ±inf clipped, as NumPy
