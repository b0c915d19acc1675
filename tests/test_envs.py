"""Gymnasium behaviour of every registered id: API, determinism, pickling, bad input."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.passive_env_checker import env_render_passive_checker

import snac_gym
from snac_gym.cost import cost_rates
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse

ENV_IDS = list(snac_gym.ENV_IDS)


def _actions(env, count, seed=0, scale=0.3):
    env.action_space.seed(seed)
    return [env.action_space.sample() * scale for _ in range(count)]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env(env_id):
    env = gym.make(env_id)
    # "human" needs a display: CI checks the headless mode explicitly below.
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_rgb_array_render_is_headless(env_id):
    env = gym.make(env_id, render_mode="rgb_array", render_width=96, render_height=64)
    env.reset(seed=0)
    env_render_passive_checker(env.unwrapped)
    image = env.render()
    assert image.shape == (64, 96, 3) and image.dtype == np.uint8
    assert image.std() > 1.0  # the arm is drawn, not a blank frame
    env.close()


def test_human_render_without_display_is_a_clear_error(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="needs a display"):
        gym.make(ENV_IDS[0], render_mode="human")


def _rollout(env_id, seed, actions, **kwargs):
    env = gym.make(env_id, **kwargs)
    obs, info = env.reset(seed=seed)
    observations, rewards = [obs], []
    for action in actions:
        obs, reward, *_ = env.step(action)
        observations.append(obs)
        rewards.append(reward)
    env.close()
    return np.array(observations), np.array(rewards), info


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeded_rollouts_are_bit_identical(env_id):
    env = gym.make(env_id)
    actions = _actions(env, 60)
    first = _rollout(env_id, 11, actions)
    second = _rollout(env_id, 11, actions)
    other = _rollout(env_id, 12, actions)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
    assert not np.array_equal(first[0][0], other[0][0])


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_restores_the_saved_simulator_state(env_id):
    options = {"q0": PAPER_Q0}
    env = gym.make(env_id)
    actions = _actions(env, 40)
    env.reset(seed=0, options=options)
    for action in actions:  # leave the arm moving, motors set
        env.step(action)
    obs, _ = env.reset(seed=0, options=options)
    np.testing.assert_array_equal(obs[6:12], 0.0)
    replay = [env.step(a)[0] for a in actions]
    fresh = gym.make(env_id)
    fresh.reset(seed=0, options=options)
    np.testing.assert_array_equal(np.array(replay), np.array([fresh.step(a)[0] for a in actions]))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_pickled_env_continues_identically(env_id):
    env = gym.make(env_id)
    actions = _actions(env, 40)
    env.reset(seed=5)
    for action in actions[:20]:
        env.step(action)
    clone = pickle.loads(pickle.dumps(env))
    original = np.array([env.step(a)[0] for a in actions[20:]])
    copied = np.array([clone.step(a)[0] for a in actions[20:]])
    np.testing.assert_array_equal(original, copied)
    # the RNG travelled too: the next random episode is the same
    np.testing.assert_array_equal(env.reset()[0], clone.reset()[0])


def test_paper_seed_pose_observation_matches_kinematics():
    env = gym.make("snac_gym/UR10Reach-v0")
    obs, info = env.reset(options={"q0": PAPER_Q0, "target": PAPER_TARGET})
    base = env.unwrapped
    fields = base.obs_layout.unpack(obs)
    np.testing.assert_allclose(fields.q, PAPER_Q0, atol=1e-12)
    np.testing.assert_allclose(fields.x, base.kinematics.forward(np.array(PAPER_Q0)), atol=1e-12)
    # PyBullet's own link state agrees with the observation
    np.testing.assert_allclose(base.kinematics.base_to_world(fields.x), base.arm.ee_world_position(), atol=1e-6)
    np.testing.assert_allclose(fields.x_d, PAPER_TARGET)
    np.testing.assert_allclose(fields.e, fields.x - fields.x_d)
    np.testing.assert_array_equal(fields.xdot_d, 0.0)
    assert base.dt == pytest.approx(1 / 125)


def test_velocity_motors_follow_the_command():
    env = gym.make("snac_gym/UR10Reach-v0")
    obs, _ = env.reset(options={"q0": PAPER_Q0})
    u = np.array([0.1, -0.1, 0.2, 0.1, -0.2, 0.3])
    q_start = obs[:6].copy()
    for _ in range(50):
        obs, *_ = env.step(u)
    np.testing.assert_allclose(obs[6:12], u, atol=1e-3)
    np.testing.assert_allclose(obs[:6], q_start + 50 * env.unwrapped.dt * u, atol=5e-3)


def test_tracking_reference_moves_on_the_paper_circle():
    env = gym.make("snac_gym/UR10EllipseTrack-v0")
    obs, _ = env.reset(options={"q0": PAPER_Q0})
    circle = Ellipse.paper_circle()
    for _ in range(10):
        obs, *_ = env.step(np.zeros(6))
    fields = env.unwrapped.obs_layout.unpack(obs)
    t = 10 * env.unwrapped.dt
    np.testing.assert_allclose(fields.x_d, circle.position(t))
    np.testing.assert_allclose(fields.xdot_d, circle.velocity(t))
    np.testing.assert_allclose(fields.x_c, circle.centre)


def test_dense_reward_is_the_paper_cost_of_the_logged_errors_and_commands():
    env = gym.make("snac_gym/UR10EllipseTrack-v0")
    obs, _ = env.reset(seed=3)
    errors, commands, rewards, smooth = [], [], [], []
    for action in _actions(env, 30, scale=2.0):  # some exceed the limits and get clipped
        errors.append(env.unwrapped.obs_layout.unpack(obs).e.copy())
        obs, reward, _, _, info = env.step(action)
        commands.append(info["command"])
        rewards.append(reward)
        smooth.append(info["cost_smoothness"])
        assert np.all(np.abs(info["command"]) <= env.unwrapped.velocity_limits)
    rates = cost_rates(np.array(errors), np.array(commands), env.unwrapped.dt)
    np.testing.assert_allclose(-np.array(rewards), rates.error + rates.effort, rtol=1e-12)
    np.testing.assert_allclose(smooth, rates.smoothness, rtol=1e-12)


def test_sparse_reward_and_success_flag():
    env = gym.make("snac_gym/UR10Reach-v0", reward_type="sparse", terminate_on_success=True)
    q0 = np.array(PAPER_Q0)
    target = env.unwrapped.kinematics.forward(q0)  # already there: success on the first step
    env.reset(options={"q0": q0, "target": target})
    _, reward, terminated, truncated, info = env.step(np.zeros(6))
    assert info["is_success"] and reward == 0.0 and terminated and not truncated
    env.reset(options={"q0": q0})
    _, reward, terminated, _, info = env.step(np.zeros(6))
    assert not info["is_success"] and reward == -1.0 and not terminated


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_truncation_after_max_steps(env_id):
    env = gym.make(env_id, max_steps=3)
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_out_of_range_action_is_clipped():
    env = gym.make("snac_gym/UR10Reach-v0")
    env.reset(seed=0)
    *_, info = env.step(np.full(6, 100.0))
    np.testing.assert_array_equal(info["command"], env.unwrapped.velocity_limits)


@pytest.mark.parametrize(
    "action, message",
    [
        (np.array([np.nan, 0, 0, 0, 0, 0]), "NaN or inf"),
        (np.array([np.inf, 0, 0, 0, 0, 0]), "NaN or inf"),
        (np.zeros(5), r"shape \(6,\)"),
        (np.zeros((2, 6)), r"shape \(6,\)"),
        ("fast", "joint velocities"),
    ],
)
def test_bad_actions_raise_value_error(action, message):
    env = gym.make("snac_gym/UR10Reach-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)


@pytest.mark.parametrize(
    "env_id, options, message",
    [
        ("snac_gym/UR10Reach-v0", {"target": [2.5, 0.0, 0.5]}, r"\[2.5, 0.0, 0.5\].*outside the reachable workspace"),
        ("snac_gym/UR10Reach-v0", {"target": [1.0, 2.0]}, "target must be 3"),
        ("snac_gym/UR10Reach-v0", {"goal": [0, 0, 0]}, "unknown reset options"),
        ("snac_gym/UR10Reach-v0", {"q0": [0.0] * 5}, "6 finite joint angles"),
        ("snac_gym/UR10Reach-v0", {"q0": [0, 0, 4.0, 0, 0, 0]}, r"q0'\]\[2\] = 4.0 rad is outside the joint limits"),
        ("snac_gym/UR10EllipseTrack-v0", {"ellipse": {"centre": [-0.7, 0, 0.5], "radius": 1.5}}, "outside the reachable"),
        ("snac_gym/UR10EllipseTrack-v0", {"ellipse": {"center": [-0.7, 0, 0.5], "radius": 0.1}}, "unknown ellipse keys"),
    ],
)
def test_bad_reset_options_raise(env_id, options, message):
    env = gym.make(env_id)
    with pytest.raises(ValueError, match=message):
        env.reset(options=options)


def test_constructor_rejects_unknown_and_invalid_arguments():
    with pytest.raises(TypeError, match="frequency"):
        gym.make("snac_gym/UR10Reach-v0", frequency=125)
    with pytest.raises(ValueError, match="reward_type"):
        gym.make("snac_gym/UR10Reach-v0", reward_type="shaped")
    with pytest.raises(ValueError, match="n_substeps"):
        gym.make("snac_gym/UR10Reach-v0", n_substeps=0)
    with pytest.raises(ValueError, match="unknown robot"):
        gym.make("snac_gym/UR10Reach-v0", robot="kuka")


def test_step_before_reset_is_an_error():
    env = gym.make("snac_gym/UR10Reach-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))


def test_other_ur_arms_run_through_the_same_code():
    env = gym.make("snac_gym/UR10Reach-v0", robot="ur5")
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    assert base.kinematics.robot == "ur5" and obs.shape == (base.obs_layout.size,)
    assert base.sample_space.contains(base.reference.target)
    obs, *_ = env.step(np.zeros(6))
    np.testing.assert_allclose(base.kinematics.base_to_world(obs[12:15]), base.arm.ee_world_position(), atol=1e-6)


def test_env_docstrings_document_every_section():
    for env_id in ENV_IDS:
        doc = gym.spec(env_id).entry_point
        cls = gym.make(env_id).unwrapped.__class__
        for section in ("## Observation Space", "## Action Space", "## Episode End", "## Arguments", "## Version History"):
            assert section in cls.__doc__, (doc, section)
