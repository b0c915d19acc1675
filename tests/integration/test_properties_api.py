"""Property-based tests (Hypothesis) of the public API's boundaries: whatever comes in (finite, non-finite,
of the wrong type, of the wrong shape, huge), the answer is a ``ValueError`` whose message names the
argument, or a correct result. Never another exception, a hang or a NaN that scores.

Each test runs a bounded number of examples from a fixed seed (``derandomize``), so the suite is the same
in every run; each example must end within :data:`EXAMPLE_BOUND_S` (an alarm ends one that hangs).
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from snac_gym.evaluation import EvaluationConfig

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.control.cost import trajectory_cost
from snac_gym.model.model_error import ModelError
from snac_gym.policies import make_policy

ID = "snac_gym/UR10Reach-v0"
#: Seconds one example may take before it counts as a hang.
EXAMPLE_BOUND_S = 10

SETTINGS = settings(
    max_examples=60,
    derandomize=True,
    database=None,
    deadline=timedelta(seconds=EXAMPLE_BOUND_S),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)


@contextlib.contextmanager
def bounded(seconds: float = EXAMPLE_BOUND_S) -> Iterator[None]:
    """Fail an example that runs longer than ``seconds`` (Hypothesis' deadline only reports one that ends)."""

    def hang(signum, frame):
        raise TimeoutError(f"an example ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# -- strategies ----------------------------------------------------------------------------------------
HUGE = 10**12
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-HUGE, HUGE),
    st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(max_magnitude=1e3),
    st.text(max_size=6),
    st.just(b"0.1"),
)


def arrays_near(shape: tuple[int, ...]) -> st.SearchStrategy:
    """Arrays of ``shape`` or of a neighbouring shape, of real, complex, bool or string dtype, finite or not."""
    shapes = st.one_of(st.just(shape), hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=7))
    dtypes = st.one_of(
        hnp.floating_dtypes(sizes=(32, 64)),
        hnp.integer_dtypes(sizes=(8, 64)),
        hnp.complex_number_dtypes(sizes=(128,)),
        hnp.boolean_dtypes(),
        st.just(np.dtype("<U3")),
    )
    return st.one_of(
        hnp.arrays(dtypes, shapes),
        hnp.arrays(np.float64, st.just(shape), elements=st.floats(-1e6, 1e6)),  # the right shape, finite
        st.lists(scalars, max_size=8),
        scalars,
    )


def _refused_naming(exc: ValueError, *names: str) -> None:
    assert any(name in str(exc) for name in names), f"{exc!s} names none of {names}"


# -- envs ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env():
    env = gym.make(ID, physics="kinematic")
    env.reset(seed=0)
    yield env
    env.close()


@SETTINGS
@given(action=arrays_near((6,)))
def test_step_refuses_or_applies_a_finite_clipped_command(env, action):
    with bounded():
        try:
            obs, reward, terminated, truncated, info = env.step(action)
        except ValueError as exc:
            _refused_naming(exc, "action")
            return
    raw = np.asarray(action)
    assert raw.dtype.kind in "iuf" and raw.shape == (6,) and np.isfinite(raw.astype(float)).all()
    limits = env.unwrapped.velocity_limits
    assert np.all(np.abs(info["command"]) <= limits + 1e-12) and np.isfinite(obs).all() and np.isfinite(reward)
    if terminated or truncated:
        env.reset(seed=0)


@SETTINGS
@pytest.mark.filterwarnings("ignore:.*max_steps.*is deprecated:DeprecationWarning")
@given(name=st.sampled_from(["dt", "n_substeps", "max_steps"]), value=scalars)
def test_env_timing_arguments_are_refused_by_name_or_give_a_working_env(name, value):
    with bounded():
        try:
            made = gym.make(ID, physics="kinematic", **{name: value})
        except ValueError as exc:
            _refused_naming(exc, name)
            return
        try:
            obs, _ = made.reset(seed=0)
            obs, *_ = made.step(np.zeros(6))
            assert np.isfinite(obs).all()
        finally:
            made.close()
    assert not isinstance(value, (bool, str, bytes, complex))  # None: the documented default


@pytest.fixture(scope="module")
def goal_env():
    env = gym.make("snac_gym/UR10ReachGoal-v0")
    env.reset(seed=0)
    yield env.unwrapped
    env.close()


@SETTINGS
@given(achieved=arrays_near((3,)), desired=arrays_near((3,)))
def test_a_goal_scores_only_when_it_is_a_finite_goal_of_the_right_size(goal_env, achieved, desired):
    for method in (goal_env.compute_reward, goal_env.compute_terminated, goal_env.compute_truncated):
        with bounded():
            try:
                result = np.asarray(method(achieved, desired, {}))
            except ValueError as exc:
                _refused_naming(exc, "achieved_goal", "desired_goal", "one shape")
                continue
        a, d = np.asarray(achieved), np.asarray(desired)
        assert a.dtype.kind in "iuf" and d.dtype.kind in "iuf" and a.shape == d.shape and a.shape[-1:] == (3,)
        assert np.isfinite(a.astype(float)).all() and np.isfinite(d.astype(float)).all()
        assert result.shape == a.shape[:-1]
        if method is goal_env.compute_reward:  # the independent distance: -(‖a − d‖ > tolerance)
            reached = np.linalg.norm(a.astype(float) - d.astype(float), axis=-1) <= goal_env.success_tolerance
            assert np.array_equal(result == 0, reached)


@SETTINGS
@given(num_envs=st.one_of(scalars, st.integers(-5, 8), st.just(10**9)))
def test_make_vec_refuses_a_count_by_name_or_builds_that_many(num_envs):
    with bounded():
        try:
            vector = gym.make_vec(ID, num_envs, vectorization_mode="vector_entry_point")
        except (ValueError, TypeError) as exc:  # gymnasium's own make_vec checks come first for some types
            _refused_naming(exc, "num_envs")
            return
    assert vector.num_envs == num_envs and 1 <= num_envs
    vector.close()


# -- cost, model error, policies, the evaluator's options -------------------------------------------------
@SETTINGS
@given(errors=arrays_near((4, 3)), commands=arrays_near((4, 6)), dt=scalars)
def test_trajectory_cost_refuses_by_name_or_equals_the_sum_of_its_terms(errors, commands, dt):
    with bounded():
        try:
            total = float(trajectory_cost(errors, commands, dt).total)
        except ValueError as exc:
            _refused_naming(exc, "error", "command", "dt", "trajectory", "Q", "R", "same number")
            return
    e, u = np.asarray(errors, dtype=float), np.asarray(commands, dtype=float)
    udot = np.diff(np.vstack([np.zeros((1, u.shape[1])), u]), axis=0) / dt
    expected = dt * (np.sum(e * e) + np.sum(u * u) + np.sum(udot * udot))
    assert np.isfinite(total) and total >= 0 and total == pytest.approx(expected, rel=1e-9, abs=1e-12)


@SETTINGS
@given(
    field=st.sampled_from(["joint_offset", "link_scale", "tool_offset"]),
    value=st.one_of(
        scalars, st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-9, 9)), max_size=7)
    ),
)
def test_a_model_error_is_refused_by_name_or_lies_in_its_documented_range(field, value):
    try:
        error = ModelError(**{field: value})
    except ValueError as exc:
        _refused_naming(exc, field)
        return
    if field == "link_scale":
        assert -1 < error.link_scale <= 1
    else:
        values = np.asarray(getattr(error, field), dtype=float)
        assert np.isfinite(values).all() and np.all(np.abs(values) <= (np.pi if field == "joint_offset" else 1.0))


@pytest.fixture(scope="module")
def policies(env):
    made = {name: make_policy(name, env.unwrapped) for name in ("snac", "lqr", "dls")}
    for policy in made.values():
        policy.reset(seed=0)
    return made


@SETTINGS
@given(name=st.sampled_from(["snac", "lqr", "dls"]), observation=arrays_near((18,)))
def test_act_refuses_an_observation_by_name_or_returns_a_finite_command(env, policies, name, observation):
    size = env.unwrapped.obs_layout.size
    with bounded():
        try:
            command = policies[name].act(observation)
        except ValueError as exc:
            _refused_naming(exc, "observation")
            return
    raw = np.asarray(observation)
    assert raw.shape == (size,) and raw.dtype.kind in "iuf" and np.isfinite(raw.astype(float)).all()
    assert np.isfinite(command).all()


@SETTINGS
@given(
    field=st.sampled_from(
        [
            "samples",
            "seed",
            "q_scale",
            "effort_tolerance",
            "success_threshold",
            "plots",
            "workers",
            "chunk_size",
            "progress",
        ]
    ),
    value=scalars,
)
def test_evaluation_options_are_refused_by_name_or_validate(field, value):
    config = EvaluationConfig(out=Path("unused"), **{field: value})
    try:
        config.validate()
    except ValueError as exc:
        _refused_naming(exc, field, field.replace("_", "-"), field.replace("_", " "))
        return
    assert not isinstance(value, (str, bytes, complex)) and value is not None
