"""The goal-relative PPO action (``ppo-workspace``): at a = 0 it is joint-goal, the batch and the single
protocols agree, the training env steps the same commands, and the joint-limit reward term."""

from __future__ import annotations

import json

import numpy as np
import pytest
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import generate_samples

from snac_gym.observation import ObservationLayout
from snac_gym.policies import make_policy
from snac_gym.ppo import PolicyFile
from snac_gym.ppo.config import ConfigError, validate_config
from snac_gym.ppo.envs import RewardSpec
from snac_gym.ppo.features import FeatureSpec, action_size, feature_size
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

DT = 0.008
GOAL_CONFIG = "snac_gym/ppo/configs/goal/{}.json"


def _policy_file(tmp_path, task, action_bias=None, seed=0):
    """A goal-relative policy file: random hidden layer, zero output weights and ``action_bias`` as the output."""
    layout = ObservationLayout(6, 3)
    spec = FeatureSpec(action="goal-relative")
    width, outputs = feature_size(layout, spec), action_size(layout, spec)
    assert (width, outputs) == (4 * 3 + 6 + 3, 4)
    rng = np.random.default_rng(seed)
    bias = np.zeros(outputs, np.float32) if action_bias is None else np.asarray(action_bias, np.float32)
    zero = action_bias is not None or seed == 0  # a constant action: the output layer's bias alone
    weights = (
        np.zeros((outputs, 8), np.float32) if zero else rng.normal(scale=0.5, size=(outputs, 8)).astype(np.float32)
    )
    file = PolicyFile(
        hidden=((rng.normal(size=(8, width)).astype(np.float32), rng.normal(size=8).astype(np.float32)),),
        action_layer=(weights, bias),
        activation="tanh",
        obs_mean=None,
        obs_var=None,
        obs_epsilon=1e-8,
        obs_clip=10.0,
        features=spec,
        metadata={"task": task, "robot": "ur10", "layout": {"n_joints": 6, "task_dim": 3, "size": layout.size}},
    )
    return file.save(tmp_path / f"{task}_{seed}.npz")


def _run(name, task, samples, steps, use_batch=True, **kwargs):
    context = policy_context("ur10", DT, task)
    return simulate_kinematic(context, lambda: make_policy(name, context, **kwargs), samples, steps,
                              [0] * len(samples), use_batch, name)  # fmt: skip


@pytest.fixture(scope="module")
def workspace_samples():
    context = policy_context("ur10", DT, "track")
    kin = context.kinematics
    space = SampleSpace.workspace(kin)
    return {task: generate_samples(kin, space, 8, task, range(4)) for task in ("reach", "track")}


@pytest.mark.parametrize("task", ["reach", "track"])
def test_a_zero_action_is_the_joint_goal_controller(tmp_path, workspace_samples, task):
    path = _policy_file(tmp_path, task)
    samples = workspace_samples[task]
    ppo = _run("ppo", task, samples, 200, model_path=str(path))
    goal = _run("joint-goal", task, samples, 200)
    np.testing.assert_allclose(ppo.commands, goal.commands, rtol=0, atol=1e-12)
    # the effort knob scales the joint-space gain as joint-goal's gain does
    np.testing.assert_allclose(
        _run("ppo", task, samples, 50, model_path=str(path), action_scale=1.5).commands,
        _run("joint-goal", task, samples, 50, gain=3.0).commands,
        rtol=0,
        atol=1e-12,
    )


def test_the_action_map_against_an_independent_computation(tmp_path, workspace_samples):
    """A constant a = (a₀, a₁..₃): u = sat(θ̇* + 2(1 + a₀)(θ* − θ) + argmin ‖Ju − v‖² + λ²‖u‖²), v = 4(‖e‖ + 10⁻⁴)a₁..₃,
    the last term by the normal equations (not the package's Jᵀ(JJᵀ + λ²I)⁻¹ form); θ* from nearest_goals
    (a reach goal stays put: θ̇* = 0)."""
    from snac_gym.model.joint_goal import nearest_goals

    a = np.array([-0.5, 0.3, -0.2, 0.4], dtype=np.float32).astype(float)  # as the file stores it
    path = _policy_file(tmp_path, "reach", action_bias=a)
    context = policy_context("ur10", DT, "reach")
    kin, limits = context.kinematics, context.velocity_limits
    policy = make_policy("ppo", context, model_path=str(path))
    for sample in workspace_samples["reach"]:
        policy.reset()
        x, target = kin.forward(sample.q0), sample.reference.position(0.0)
        obs = context.layout.pack(sample.q0, np.zeros(6), x, target, np.zeros(3), target)
        goal, found = nearest_goals(kin, sample.q0, target)
        assert found.all()
        jac = kin.jacobian(sample.q0)
        v = 4.0 * (np.linalg.norm(x - target) + 1e-4) * a[1:]
        raw = 2.0 * (1 + a[0]) * (goal - sample.q0) + np.linalg.solve(jac.T @ jac + 1e-4 * np.eye(6), jac.T @ v)
        expected = raw / max(1.0, np.max(np.abs(raw) / limits))
        np.testing.assert_allclose(policy.act(obs), expected, rtol=1e-9, atol=1e-9)


def test_act_and_act_batch_agree(tmp_path, workspace_samples):
    path = _policy_file(tmp_path, "track", seed=3)
    samples = workspace_samples["track"]
    batch = _run("ppo", "track", samples, 80, model_path=str(path))
    single = _run("ppo", "track", samples, 80, use_batch=False, model_path=str(path))
    # act takes J(θ) from Pinocchio, act_batch from the batched kernel: they differ in the last bits, which
    # 80 closed-loop steps of a random network grow to ~1e-10
    np.testing.assert_allclose(single.commands, batch.commands, rtol=0, atol=1e-8)


@pytest.mark.rl
@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_training_env_steps_what_the_policy_commands(tmp_path, task):
    """PPOVecEnv's goal-relative commands equal PPOPolicy's on the same episodes (the features too)."""
    from snac_gym.ppo.vec_env import PPOVecEnv

    config = json.load(open(GOAL_CONFIG.format(task)))
    path = _policy_file(tmp_path, task, seed=5)
    vec = PPOVecEnv(config, num_envs=3)
    vec.seed(11)
    features = vec.reset()
    context = policy_context("ur10", DT, task)
    policy = make_policy("ppo", context, model_path=str(path))
    policy.reset_batch([0, 0, 0])
    file = policy.model
    for _ in range(40):
        obs = vec.episodes.observations()
        expected = policy.act_batch(obs)
        action = np.clip(file.network_action(features), -1, 1).astype(np.float32)
        vec.step_async(action)
        features, *_ = vec.step_wait()
        np.testing.assert_allclose(vec.episodes.last_command, expected, rtol=0, atol=1e-6)


def test_the_limit_term_and_its_validation():
    spec = RewardSpec(type="cost", limit_penalty=100.0)
    lower, upper = -np.ones(3), np.ones(3)
    q = np.array([[0.0, 0.5, -0.5], [1.2, -1.1, 0.0]])
    np.testing.assert_allclose(spec.limit_term(q, lower, upper, 0.008), [0.0, 100 * 0.008 * 0.3])
    with pytest.raises(ValueError, match="limit_penalty"):
        RewardSpec(type="cost", limit_penalty=-1.0)
    config = json.load(open(GOAL_CONFIG.format("reach")))
    config["reward"]["limit_penalty"] = -1
    with pytest.raises(ConfigError, match="reward.limit_penalty"):
        validate_config(config)


def test_a_goal_relative_spec_without_its_goal_state_is_refused(tmp_path):
    from snac_gym.ppo.features import command, observation_features

    layout, spec = ObservationLayout(6, 3), FeatureSpec(action="goal-relative")
    assert PolicyFile.load(_policy_file(tmp_path, "reach")).features.goal_relative
    with pytest.raises(ValueError, match="needs its goal state"):
        observation_features(np.zeros(layout.size), layout, spec)
    with pytest.raises(ValueError, match="needs its goal state"):
        command(np.zeros(4), np.zeros(layout.size), layout, np.ones(6), spec, jacobians=np.zeros((3, 6)))
    # a goal-relative spec's version is 4 and no other
    with pytest.raises(ValueError, match="does not go with action 'goal-relative'"):
        FeatureSpec.from_dict({**spec.to_dict(), "version": 3})


@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_withdrawn_workspace_policy_refuses_without_a_file_and_runs_one_it_is_given(tmp_path, task):
    """``ppo-workspace`` ships no policy (no learned correction beat joint-goal: docs/ppo.md): without
    ``model_path`` it refuses in one line naming why and what to use; with a goal-relative file it runs it."""
    from snac_gym.ppo import MissingPolicyFileError, WorkspacePPOPolicy, shipped_model_path

    assert not shipped_model_path(task, "models/workspace").exists()
    context = policy_context("ur10", DT, task)
    with pytest.raises(MissingPolicyFileError, match=r"^ppo-workspace is withdrawn: .*use joint-goal") as refused:
        make_policy("ppo-workspace", context)
    assert "\n" not in str(refused.value)
    path = _policy_file(tmp_path, task)
    policy = make_policy("ppo-workspace", context, model_path=str(path))
    assert isinstance(policy, WorkspacePPOPolicy) and policy.model.features.goal_relative
