"""Behaviour cloning of the reference into the goal-relative actor (snac_gym/ppo/cloning.py): the target action
reproduces a command the action can express, a = 0 is joint-goal's command, the fitted actor is a policy file
that acts as fitted, and its weights go into an SB3 model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.ppo.cloning import action_columns, cloned_policy_file, fit_actor, load_actor, target_actions
from snac_gym.ppo.config import load_config
from snac_gym.ppo.features import FeatureSpec, GoalState, goal_relative_command, observation_features
from snac_gym.ppo.policy_file import PolicyFile
from snac_gym.ppo.train import build_model, build_vec_env

LAYOUT = ObservationLayout(6, 3)
SPEC = FeatureSpec(action="goal-relative")


def _rows(count: int, seed: int = 0):
    """Observations, Jacobians and goal states of ``count`` random arms with targets 5–30 cm off."""
    kin = shared_kinematics("ur10")
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0, 2.0, (count, 6))
    x = kin.forward_batch(q)
    x_d = x + rng.normal(0, 0.15, (count, 3))
    xdot_d = rng.normal(0, 0.05, (count, 3))
    obs = np.concatenate([LAYOUT.pack(q[i], np.zeros(6), x[i], x_d[i], xdot_d[i], x_d[i])[None]
                          for i in range(count)])  # fmt: skip
    goal = GoalState(q + rng.normal(0, 0.5, (count, 6)), rng.normal(0, 0.1, (count, 6)),
                     kin.lower_limits, kin.upper_limits)  # fmt: skip
    return obs, kin.jacobian_batch(q), goal, kin.velocity_limits


def test_the_target_reproduces_a_command_the_action_expresses():
    obs, jac, goal, limits = _rows(64)
    rng = np.random.default_rng(1)
    actions = rng.uniform(-0.9, 0.9, (64, 4))
    big = np.full(6, 1e3)  # no saturation: the command is the affine form itself
    commands = goal_relative_command(actions, obs, LAYOUT, jac, big, SPEC, goal)
    found, residual = target_actions(obs, commands, LAYOUT, jac, SPEC, goal, ridge=0.0)
    np.testing.assert_allclose(found, actions, atol=1e-6)
    assert residual.max() < 1e-8
    # the affine form is the command before saturation
    base, columns = action_columns(obs, LAYOUT, jac, SPEC, goal)
    np.testing.assert_allclose(base + np.einsum("bmi,bi->bm", columns, actions), commands, atol=1e-12)
    assert limits.shape == (6,)


def test_a_zero_action_is_joint_goal_and_the_target_of_its_command_is_zero():
    obs, jac, goal, _ = _rows(32, seed=2)
    big = np.full(6, 1e3)
    joint_goal = goal.velocity + 2.0 * (goal.goal - obs[:, LAYOUT.slices["q"]])
    np.testing.assert_allclose(goal_relative_command(np.zeros((32, 4)), obs, LAYOUT, jac, big, SPEC, goal),
                               joint_goal, atol=1e-12)  # fmt: skip
    found, _ = target_actions(obs, joint_goal, LAYOUT, jac, SPEC, goal)
    assert np.abs(found).max() < 1e-6


def test_a_command_out_of_reach_is_clipped_with_its_residual_reported():
    obs, jac, goal, _ = _rows(16, seed=3)
    base, columns = action_columns(obs, LAYOUT, jac, SPEC, goal)
    far = base + 5.0 * columns[:, :, 0]  # a₀ = 5: beyond the box
    found, residual = target_actions(obs, far, LAYOUT, jac, SPEC, goal, ridge=0.0)
    np.testing.assert_allclose(found[:, 0], 1.0)
    np.testing.assert_allclose(residual, 0.8, rtol=1e-6)  # (5 − 1) / 5 of the way missed


def test_the_fitted_actor_is_a_policy_file_that_acts_as_fitted(tmp_path):
    torch = pytest.importorskip("torch")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a tiny net: more threads only contend (40 s on a loaded 2-core host)
    obs, jac, goal, _ = _rows(128, seed=4)
    features = observation_features(obs, LAYOUT, SPEC, 1.0, goal)
    targets = np.tanh(features[:, :4] * 0.8)  # a smooth map the net can learn
    try:
        hidden, output = fit_actor(features, targets, epochs=60, batch_size=32, learning_rate=3e-3)
    finally:
        torch.set_num_threads(threads)
    config = {"task": "reach", "robot": "ur10", "features": SPEC.to_dict(), "ppo": {"activation": "tanh"}}
    path = cloned_policy_file(hidden, output, config, LAYOUT).save(tmp_path / "clone.npz")
    policy = PolicyFile.load(path)
    acted = policy.action(obs, LAYOUT, 1.0, goal)
    untrained = np.mean((targets - 0.0) ** 2)
    assert np.mean((acted - targets) ** 2) < 0.1 * untrained


def test_the_clone_goes_into_an_sb3_actor_that_predicts_the_same(tmp_path):
    pytest.importorskip("stable_baselines3")
    # the rl extra, checked just above
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO

    rng = np.random.default_rng(5)
    width = 4 * 3 + 6 + 3
    hidden = ((rng.normal(size=(8, width)).astype(np.float32), rng.normal(size=8).astype(np.float32)),)
    output = (rng.normal(size=(4, 8)).astype(np.float32), rng.normal(size=4).astype(np.float32))
    config = {"task": "reach", "robot": "ur10", "features": SPEC.to_dict(), "ppo": {"activation": "tanh"}}
    policy = cloned_policy_file(hidden, output, config, LAYOUT)

    class Box(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (width,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)

    model = PPO("MlpPolicy", Box(), policy_kwargs={"net_arch": {"pi": [8], "vf": [8]}, "activation_fn": torch.nn.Tanh},
                n_steps=8, batch_size=8, device="cpu")  # fmt: skip
    load_actor(model, policy)
    inputs = rng.normal(size=(5, width)).astype(np.float32)
    with torch.no_grad():
        mean = model.policy.get_distribution(torch.as_tensor(inputs)).distribution.mean.numpy()
    np.testing.assert_allclose(mean, policy.network_action(inputs), atol=1e-5)
    with pytest.raises(ValueError, match="hidden layers"):
        load_actor(model, cloned_policy_file((*hidden, (np.zeros((8, 8), np.float32), np.zeros(8, np.float32))),
                                             output, config, LAYOUT))  # fmt: skip


def test_a_pull_below_the_floor_is_raised_to_it_and_the_rest_fitted_again():
    obs, jac, goal, _ = _rows(32, seed=6)
    rng = np.random.default_rng(7)
    actions = np.column_stack([np.full(32, -0.9), rng.uniform(-0.5, 0.5, (32, 3))])
    base, columns = action_columns(obs, LAYOUT, jac, SPEC, goal)
    commands = base + np.einsum("bmi,bi->bm", columns, actions)
    same, _ = target_actions(obs, commands, LAYOUT, jac, SPEC, goal, ridge=0.0)
    np.testing.assert_allclose(same, actions, atol=1e-6)  # the default floor, −1, leaves it
    floored, residual = target_actions(obs, commands, LAYOUT, jac, SPEC, goal, ridge=0.0, pull_floor=-0.5)
    np.testing.assert_allclose(floored[:, 0], -0.5)
    # a₁..₃ is the least-squares fit of what the raised pull leaves: its residual is orthogonal to the task columns
    missed = commands - base - np.einsum("bmi,bi->bm", columns, floored)
    inside = (np.abs(floored[:, 1:]) < 1).all(axis=1)  # rows whose refit was not clipped
    assert inside.sum() >= 16
    assert np.abs(np.einsum("bmi,bm->bi", columns[inside, :, 1:], missed[inside])).max() < 1e-8
    assert (residual > 1e-3).all()  # the raised pull is not expressible exactly


def test_a_config_with_init_from_builds_a_model_whose_actor_is_the_file(tmp_path):
    """``init_from`` (the PPO fine-tuning from a clone): build_model loads the file's actor; a bad path is refused."""
    pytest.importorskip("stable_baselines3")
    import torch  # the rl extra, checked just above

    config = load_config("snac_gym/ppo/configs/goal/reach.json")
    config["vec_env"].update(n_envs=2, kind="dummy")
    config["ppo"].update(n_steps=16, batch_size=32, n_epochs=1, net_arch={"pi": [8, 8], "vf": [8, 8]})
    rng = np.random.default_rng(8)
    width = 4 * 3 + 6 + 3
    hidden = tuple(
        (rng.normal(size=(8, w)).astype(np.float32), rng.normal(size=8).astype(np.float32)) for w in (width, 8)
    )
    output = (rng.normal(size=(4, 8)).astype(np.float32), rng.normal(size=4).astype(np.float32))
    path = cloned_policy_file(hidden, output, json.loads(json.dumps(config)), LAYOUT).save(tmp_path / "clone.npz")
    venv = build_vec_env(config)
    try:
        model = build_model({**config, "init_from": str(path)}, venv)
        inputs = rng.normal(size=(3, width)).astype(np.float32)
        with torch.no_grad():
            mean = model.policy.get_distribution(torch.as_tensor(inputs)).distribution.mean.numpy()
        np.testing.assert_allclose(mean, PolicyFile.load(path).network_action(inputs), atol=1e-5)
        with pytest.raises(FileNotFoundError, match="does not exist"):
            build_model({**config, "init_from": str(tmp_path / "none.npz")}, venv)
    finally:
        venv.close()
