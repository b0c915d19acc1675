"""The evaluator's physics engines: one simulated arm per sample in lockstep, each rollout the env's own."""

from __future__ import annotations

import functools
import importlib.util

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation.execution.jobs import RolloutJob, policy_context, run_job
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import Kinematics, resolved_urdf_text
from snac_gym.physics.bullet import without_meshes
from snac_gym.policies import make_policy
from snac_gym.rollout import lockstep_arms, simulate_arms, simulate_env
from snac_gym.sampling import SampleSpace

PHYSICS = [
    "pybullet",
    pytest.param(
        "mujoco",
        marks=pytest.mark.skipif(
            importlib.util.find_spec("mujoco") is None, reason="the mujoco engine needs the mujoco extra"
        ),
    ),
]


def _samples(task: str, seed: int, count: int) -> tuple[tuple, tuple]:
    kinematics = Kinematics("ur10")
    samples = tuple(generate_samples(kinematics, SampleSpace.for_robot(kinematics), seed, task, range(count)))
    return samples, tuple(policy_seed(seed, task, s.index) for s in samples)


@pytest.mark.parametrize("physics", PHYSICS)
@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_lockstep_engine_is_the_env_loop_batched(task, physics):
    """Each lockstep rollout must be the env's own (the demo's loop through ``gym.make(...,
    physics=...)``) to rounding, for a stateless law and for SNAC, whose critic adapts on the
    measured state (the most sensitive to any difference)."""
    samples, seeds = _samples(task, 3, 3)
    steps = 300
    for controller in ("dls", "snac"):
        env_rollouts, _ = simulate_env(
            "ur10", task, 0.008, functools.partial(make_policy, controller), samples, steps, seeds, physics=physics
        )
        context = policy_context("ur10", 0.008, task)
        arms, plant = lockstep_arms("ur10", task, 0.008, steps, physics, len(samples))
        try:
            lockstep = simulate_arms(
                context, functools.partial(make_policy, controller, context), samples, steps, seeds, arms, plant
            )
        finally:
            arms.close()
        np.testing.assert_allclose(lockstep.commands, env_rollouts.commands, rtol=0, atol=1e-12)
        np.testing.assert_allclose(lockstep.errors, env_rollouts.errors, rtol=0, atol=1e-12)
        np.testing.assert_allclose(lockstep.q, env_rollouts.q, rtol=0, atol=1e-12)
        np.testing.assert_allclose(lockstep.final_q, env_rollouts.final_q, rtol=0, atol=1e-12)
        assert np.abs(lockstep.commands).max() > 0.05  # the arms moved


@pytest.mark.parametrize("physics", PHYSICS)
def test_a_job_does_not_depend_on_how_samples_are_chunked(physics):
    """The evaluator's results must not depend on chunk size or workers: the arms are built per job,
    so one job of three samples equals a job of two and a job of one, row for row, with and without
    per-step logs (the joint-limit margin is measured on the arm's θ either way)."""
    samples, seeds = _samples("track", 5, 3)

    def job(part: slice, keep_logs: bool = False) -> RolloutJob:
        return RolloutJob(
            "track", "snac", {}, samples[part], seeds[part], 200, 0.008, engine=physics, keep_logs=keep_logs
        )

    whole = run_job(job(slice(0, 3), keep_logs=True))
    pieces = [run_job(job(slice(0, 2))), run_job(job(slice(2, 3)))]
    pd.testing.assert_frame_equal(whole.metrics, pd.concat([p.metrics for p in pieces], ignore_index=True))
    assert [log.attrs["engine"] for log in whole.logs] == [physics] * 3
    assert [log.attrs["sample"] for log in whole.logs] == [0, 1, 2]


def test_lockstep_arms_are_simulated_only():
    with pytest.raises(
        ValueError, match=r"lockstep arms are simulated: physics must be one of \('pybullet', 'mujoco'\), got"
    ):
        lockstep_arms("ur10", "reach", 0.008, 10, "kinematic", 2)


def test_without_meshes_keeps_every_link_joint_and_inertia():
    text = resolved_urdf_text(Kinematics("ur10").urdf_path)
    stripped = without_meshes(text)
    assert "<visual" in text and "<collision" in text
    assert "<visual" not in stripped and "<collision" not in stripped and "<mesh" not in stripped
    for tag in ("<link", "<joint", "<inertia", "<mass", "<limit"):
        assert stripped.count(tag) == text.count(tag), tag
