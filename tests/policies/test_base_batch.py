"""The optional batch protocol (``reset_batch`` / ``act_batch``, snac_gym/policies/base.py) of SNAC and
the baselines: row i of ``act_batch`` equals ``act`` of a fresh object reset with seeds[i], step
after step in closed loop, for every option; and whole evaluations give the same numbers with
and without it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from snac_gym.baselines.dls import DLSPolicy
from snac_gym.baselines.lqr import LQRPolicy
from snac_gym.baselines.rnn import RNNPolicy
from snac_gym.baselines.svf import SVFPolicy
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import generate_samples

from snac_gym.policies.base import supports_batch
from snac_gym.policies.snac import SNACPolicy
from snac_gym.policies.snac_hjb import SNACHJBPolicy
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0
SEEDS = [3, 11, 0, 42, 7]
STEPS = 20

#: name -> (class, constructor arguments): the defaults and every non-default option.
CONTROLLERS = {
    "snac": (SNACPolicy, {}),
    "snac-loud": (SNACPolicy, {"command_scale": 40.0}),  # some rows saturate, some do not
    "snac-uniform": (SNACPolicy, {"initial_weights": "uniform", "initial_weight_range": (0.0, 3.0)}),
    "snac-updated-freeze": (
        SNACPolicy,
        {"weight_update": "euler_updated", "freeze_when_saturated": True, "command_scale": 40.0},
    ),
    "snac-updated": (SNACPolicy, {"weight_update": "euler_updated", "R": [1.0, 2.0, 0.5, 1.0, 3.0, 1.5]}),
    "snac-zoh": (SNACPolicy, {"weight_update": "zoh", "command_scale": 20.0, "R": "full"}),
    "snac-zoh-freeze": (SNACPolicy, {"weight_update": "zoh", "freeze_when_saturated": True, "command_scale": 40.0}),
    "snac-per-step": (
        SNACPolicy,
        {"learning_rate_unit": "per_step", "schedule_clock": "steps", "freeze_when_saturated": True},
    ),
    "dls": (DLSPolicy, {}),
    "dls-loud": (DLSPolicy, {"gain": 30.0, "damping": 0.05}),
    "svf": (SVFPolicy, {}),
    "svf-loud": (SVFPolicy, {"gain": 30.0, "nu": 5.0, "sigma0": 0.01}),
    "rnn": (RNNPolicy, {}),
    "rnn-loud": (RNNPolicy, {"gain": 100.0}),
    "rnn-euler": (RNNPolicy, {"integrator": "euler", "epsilon": 2e-3, "gain": 50.0}),
    "rnn-uncompensated": (RNNPolicy, {"velocity_compensation": False}),
    "lqr": (LQRPolicy, {}),
    "snac-hjb": (SNACHJBPolicy, {}),
    "snac-hjb-loud": (SNACHJBPolicy, {"q_scale": 400.0, "R": "full", "learning_rate": 120.0}),
    "lqr-loud": (LQRPolicy, {"q_scale": 400.0, "R": "full", "Q": [1.0, 2.0, 0.5]}),
}


def _full_r(m: int) -> np.ndarray:
    """A symmetric positive definite R that is not diagonal."""
    a = np.random.default_rng(5).normal(size=(m, m))
    return a @ a.T + m * np.eye(m)


def _make(name: str, context):
    cls, kwargs = CONTROLLERS[name]
    if kwargs.get("R") == "full":
        kwargs = {**kwargs, "R": _full_r(context.kinematics.n_joints)}
    return cls(context, **kwargs)


def _observations(context, q, x_d, xdot_d, centres, held):
    """The kinematic engine's observation rows for joint positions ``q`` (B, m)."""
    slices, x = context.layout.slices, context.kinematics.forward_batch(q)
    obs = np.empty((len(q), context.layout.size))
    obs[:, slices["q"]], obs[:, slices["qdot"]], obs[:, slices["x"]] = q, held, x
    obs[:, slices["x_d"]], obs[:, slices["xdot_d"]], obs[:, slices["x_c"]] = x_d, xdot_d, centres
    obs[:, slices["e"]] = x - x_d
    return obs


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_act_batch_rows_equal_per_sample_act(name, task):
    context = policy_context("ur10", DT, task)
    samples = generate_samples(context.kinematics, SampleSpace.for_robot(context.kinematics), 1, task, range(5))
    x_d, xdot_d, centres = reference_trajectories([s.reference for s in samples], np.arange(STEPS) * DT)
    batch = _make(name, context)
    assert supports_batch(batch)
    batch.reset_batch(SEEDS)
    singles = [_make(name, context) for _ in SEEDS]
    for policy, seed in zip(singles, SEEDS, strict=True):
        policy.reset(seed=seed)
    q = np.array([s.q0 for s in samples])
    held = np.zeros_like(q)
    limits = context.velocity_limits
    saturated_rows = set()
    for k in range(STEPS):
        obs = _observations(context, q, x_d[:, k], xdot_d[:, k], centres, held)
        expected = np.array([policy.act(row) for policy, row in zip(singles, obs.copy(), strict=True)])
        got = batch.act_batch(obs)
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12, err_msg=f"{name} {task} step {k}")
        saturated_rows.update(np.flatnonzero((np.abs(expected) >= limits * (1 - 1e-12)).any(axis=1)))
        held = np.minimum(np.maximum(expected, -limits), limits)
        q = q + held * DT
    if isinstance(batch, SNACPolicy):
        np.testing.assert_allclose(
            batch.batch_critic_weights, [p.critic_weights for p in singles], rtol=1e-10, atol=1e-12
        )
    if "loud" in name or "freeze" in name:  # the clipped branches were exercised
        assert saturated_rows


def test_batch_uniform_weights_follow_the_seeds():
    context = policy_context("ur10", DT, "reach")
    policy = SNACPolicy(context, initial_weights="uniform", seed=9)
    policy.reset_batch([4, None, 4])
    fresh = SNACPolicy(context, initial_weights="uniform", seed=9)
    fresh.reset()
    own = SNACPolicy(context, initial_weights="uniform")
    own.reset(seed=4)
    expected = [own.critic_weights, fresh.critic_weights, own.critic_weights]
    np.testing.assert_array_equal(policy.batch_critic_weights, expected)


@pytest.mark.parametrize("cls", [SNACPolicy, RNNPolicy])
def test_act_batch_before_reset_batch_is_an_error(cls):
    context = policy_context("ur10", DT, "reach")
    with pytest.raises(RuntimeError, match="reset_batch"):
        cls(context).act_batch(np.zeros((2, context.layout.size)))


def test_batch_and_per_sample_evaluations_agree(tmp_path):
    common = dict(
        samples=4,
        effort_samples=0,
        horizons={"reach": 0.4, "track": 0.4},
        chunk_size=4,
        progress=False,
        plots=False,
        controllers=("snac", "rnn", "svf", "dls"),
    )
    batched = run_evaluation(EvaluationConfig(out=tmp_path / "batch", use_batch=True, **common))
    looped = run_evaluation(EvaluationConfig(out=tmp_path / "loop", use_batch=False, **common))
    keys = ["task", "controller", "sample"]
    batched, looped = batched.sort_values(keys).reset_index(drop=True), looped.sort_values(keys).reset_index(drop=True)
    pd.testing.assert_frame_equal(batched[keys], looped[keys])
    numeric = [c for c in batched.columns if c not in keys and pd.api.types.is_float_dtype(batched[c])]
    assert "cost" in numeric and "effort_value" in numeric
    for column in numeric:
        np.testing.assert_allclose(batched[column], looped[column], rtol=1e-9, atol=1e-12, err_msg=column)
