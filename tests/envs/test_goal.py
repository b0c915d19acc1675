"""The goal-conditioned variants (snac_gym/envs/goal.py): Gymnasium-Robotics conventions and HER."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs.goal import goal_env_id
from snac_gym.tasks import TASKS

GOAL_IDS = [goal_env_id(task) for task in TASKS.values()]


@pytest.mark.rl
@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_goal_envs_pass_the_checkers_with_default_arguments(env_id):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id)
    check_env(env.unwrapped)  # default arguments, headless: "human" must not fail in a constructor
    assert env.spec.max_episode_steps == TASKS[env.unwrapped.task.name].episode_steps
    env.close()
    sb3_check_env(gym.make(env_id, physics="kinematic", action_type="normalized").unwrapped, warn=False)


@pytest.mark.parametrize("reward_type", ["sparse", "dense"])
def test_step_reward_is_compute_reward_and_it_is_vectorised(reward_type):
    env = gym.make("snac_gym/UR10EllipseTrackGoal-v0", physics="kinematic", reward_type=reward_type)
    obs, _ = env.reset(seed=1)
    base = env.unwrapped
    achieved, desired, rewards, infos = [], [], [], []
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        achieved.append(obs["achieved_goal"]), desired.append(obs["desired_goal"]), rewards.append(reward)
        infos.append(info)
        # achieved_goal is f(θ) and desired_goal x_d(t): their difference is the env's error e
        np.testing.assert_allclose(obs["achieved_goal"] - obs["desired_goal"], info["error"], atol=1e-6)
    batch = base.compute_reward(np.array(achieved), np.array(desired), infos)
    np.testing.assert_array_equal(batch, np.array(rewards, dtype=np.float32))
    distance = np.linalg.norm(np.array(achieved) - np.array(desired), axis=1)
    expected = -(distance > base.success_tolerance).astype(float) if reward_type == "sparse" else -distance
    np.testing.assert_allclose(batch, expected, rtol=1e-6)
    # A relabelled goal equal to what was achieved is a success: reward 0 (sparse), 0 m (dense).
    assert (base.compute_reward(np.array(achieved), np.array(achieved), infos) == 0).all()
    assert not base.compute_truncated(np.array(achieved), np.array(desired), infos).any()


def test_the_observation_holds_nothing_that_depends_on_the_goal():
    env = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic")
    q0 = [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62]
    first, _ = env.reset(seed=0, options={"q0": q0, "target": [-0.6, 0.3, 0.4]})
    second, _ = env.reset(seed=0, options={"q0": q0, "target": [-0.7, 0.0, 0.5]})
    np.testing.assert_array_equal(first["observation"], second["observation"])
    np.testing.assert_array_equal(first["achieved_goal"], second["achieved_goal"])
    assert not np.array_equal(first["desired_goal"], second["desired_goal"])


def test_terminate_on_success_reaches_and_ends_the_episode():
    env = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", terminate_on_success=True, success_tolerance=0.05)
    obs, _ = env.reset(seed=0, options={"q0": [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62], "target": [-0.6, 0.5, 0.4]})
    base = env.unwrapped
    for step in range(500):  # resolved rate towards the goal
        q = obs["observation"][:6].astype(float)
        error = obs["achieved_goal"] - obs["desired_goal"]
        command = -2.0 * np.linalg.pinv(base.env.kinematics.jacobian(q)) @ error
        obs, reward, terminated, truncated, info = env.step(command)
        if terminated:
            break
    assert terminated and info["is_success"] and reward == 0.0 and step < 499
    with pytest.raises(ValueError, match="sets \\['observation_dtype'\\] itself"):
        gym.make("snac_gym/UR10ReachGoal-v0", observation_dtype=np.float64)
    with pytest.raises(ValueError, match="reward_type must be one of"):
        gym.make("snac_gym/UR10ReachGoal-v0", reward_type="shaped")


def test_goal_env_pickles_mid_episode():
    env = gym.make("snac_gym/UR10EllipseTrackGoal-v0")
    env.reset(seed=3)
    env.step(env.action_space.sample() * 0)
    clone = pickle.loads(pickle.dumps(env.unwrapped))
    action = np.full(6, 0.1)
    a = env.unwrapped.step(action)[0]
    b = clone.step(action)[0]
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    env.close(), clone.close()


@pytest.mark.rl
def test_sac_with_her_trains_on_the_goal_env():
    from stable_baselines3 import SAC, HerReplayBuffer

    env = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", action_type="normalized", max_episode_steps=50)
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        learning_starts=100,
        batch_size=32,
        buffer_size=1000,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
        device="cpu",
    )
    model.learn(160)  # past learning_starts: 60 gradient steps on HER's relabelled batches
    assert model.replay_buffer.size() * model.replay_buffer.n_envs >= 160 and model.num_timesteps == 160
    assert model._n_updates > 0  # gradient steps were taken
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(action)


# -- the coarse reach preset (panda-gym's PandaReach sizes) ---------------------------------------
@pytest.mark.parametrize("robot", ["panda", "ur10"])
def test_the_coarse_reach_preset_has_panda_gyms_sizes(robot):
    """5 cm tolerance, 50 steps of 40 ms, every start at the nominal pose, goals in the 30 cm cube around its tool."""
    from gymnasium.utils.env_checker import check_env

    from snac_gym.envs.goal import coarse_reach_id
    from snac_gym.model.kinematics import Kinematics
    from snac_gym.sampling import nominal_configuration

    env = gym.make(coarse_reach_id(robot), physics="kinematic")
    check_env(env.unwrapped, skip_render_check=True)
    base = env.unwrapped
    assert base.success_tolerance == 0.05 and base.dt == 0.04 and env.spec.max_episode_steps == 50
    kinematics = Kinematics(robot)
    q_nominal = nominal_configuration(kinematics)
    centre = kinematics.forward(q_nominal)
    goals = []
    for seed in range(30):
        obs, info = env.reset(seed=seed)
        np.testing.assert_allclose(info["q0"], q_nominal)
        np.testing.assert_allclose(obs["achieved_goal"], centre, atol=1e-6)
        goals.append(obs["desired_goal"])
    goals = np.array(goals)
    assert np.all(np.abs(goals - centre) <= 0.15 + 1e-6)
    assert np.ptp(goals, axis=0).min() > 0.1  # spread over the cube, not one point
    again, _ = env.reset(seed=3)
    np.testing.assert_array_equal(again["desired_goal"], goals[3])
    steps, done = 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        done = terminated or truncated
        distance = np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])
        assert reward == (0.0 if distance <= 0.05 else -1.0) and info["is_success"] == (distance <= 0.05)
    assert steps == 50
    env.close()


def test_an_unknown_start_is_refused():
    with pytest.raises(ValueError, match=r"start must be one of \('sampled', 'nominal'\), got 'home'"):
        gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", start="home")


# -- the Cartesian action (panda-gym's end-effector control) -------------------------------------
@pytest.mark.parametrize("robot", ["panda", "ur10"])
def test_the_cartesian_preset_moves_the_tool_by_the_damped_least_squares_command(robot):
    """The ``...ReachGoalCoarseCartesian-v0`` ids: the preset's sizes, a 3-D action, and each step's joint
    velocities equal to ``argmin ‖J u − 1.25·a‖² + λ²‖u‖²`` solved by the normal equations (not the
    package's ``Jᵀ(JJᵀ + λ²I)⁻¹`` form), clipped to the limits; a straight-line command reaches the goal."""
    from snac_gym.envs.goal import coarse_reach_id
    from snac_gym.model.kinematics import Kinematics

    env = gym.make(coarse_reach_id(robot, "cartesian"), physics="kinematic")
    check_env(env.unwrapped, skip_render_check=True)
    base = env.unwrapped
    assert env.action_space.shape == (3,) and base.success_tolerance == 0.05 and env.spec.max_episode_steps == 50
    kinematics, limits = Kinematics(robot), base.env.velocity_limits
    m = kinematics.n_joints
    obs, info = env.reset(seed=4)
    q = np.asarray(info["q0"], dtype=float)
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1, 1, 3)
        jac = kinematics.jacobian(q)
        expected = np.clip(np.linalg.solve(jac.T @ jac + 1e-4 * np.eye(m), jac.T @ (1.25 * action)), -limits, limits)
        np.testing.assert_allclose(base.joint_command(action) * limits, expected, rtol=0, atol=1e-9)  # normalised
        obs, *_ = env.step(action)
        q = q + expected * base.dt
        np.testing.assert_allclose(obs["observation"][:m], q, atol=1e-5)  # float32 observation
    obs, _ = env.reset(seed=5)
    for _ in range(50):
        direction = obs["desired_goal"] - obs["achieved_goal"]
        obs, reward, terminated, truncated, info = env.step(np.clip(direction / (1.25 * base.dt) * 0.5, -1, 1))
    assert info["is_success"] and reward == 0.0
    env.close()


def test_a_bad_cartesian_action_or_speed_is_refused():
    env = gym.make("snac_gym/UR10ReachGoalCoarseCartesian-v0", physics="kinematic")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be 3 finite values"):
        env.step(np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"action must be one of \('joint', 'cartesian'\), got 'polar'"):
        gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", action="polar")
    with pytest.raises(ValueError, match="cartesian_speed must be a positive number"):
        gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", action="cartesian", cartesian_speed=0.0)
    env.close()


# -- the goal-error features (snac_gym.goal_features) ---------------------------------------------
@pytest.mark.rl
def test_the_goal_error_features_are_the_relabelled_goal_minus_the_tool_at_three_scales():
    import torch

    from snac_gym.goal_features import SCALES, GoalErrorExtractor

    env = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", action_type="normalized")
    extractor = GoalErrorExtractor(env.observation_space)
    obs, _ = env.reset(seed=3)
    other_goal = obs["desired_goal"] + np.array([0.0005, -0.02, 0.3], dtype=np.float32)  # as HER relabels
    for goal in (obs["desired_goal"], other_goal):
        batch = {key: torch.as_tensor(value[None]) for key, value in {**obs, "desired_goal": goal}.items()}
        features = extractor(batch)[0].numpy().astype(float)
        error = goal.astype(float) - obs["achieved_goal"].astype(float)
        raw = np.concatenate([obs["observation"], obs["achieved_goal"], goal]).astype(float)
        expected = np.concatenate([raw, error / SCALES[0], np.tanh(error / SCALES[1]), np.tanh(error / SCALES[2])])
        assert features.shape == (extractor.features_dim,) == expected.shape
        np.testing.assert_allclose(features, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.rl
def test_the_goal_error_features_refuse_a_space_without_goals():
    from snac_gym.goal_features import GoalErrorExtractor

    space = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (4,)), "desired_goal": gym.spaces.Box(-1, 1, (3,))})
    with pytest.raises(ValueError, match="missing achieved_goal"):
        GoalErrorExtractor(space)
    space = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (4,)), "achieved_goal": gym.spaces.Box(-1, 1, (3,)),
                             "desired_goal": gym.spaces.Box(-1, 1, (2,))})  # fmt: skip
    with pytest.raises(ValueError, match="differ"):
        GoalErrorExtractor(space)
