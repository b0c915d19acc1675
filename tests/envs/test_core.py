"""Gymnasium behaviour of every registered id: API, determinism, pickling, bad input."""

import os
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.passive_env_checker import env_render_passive_checker

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.control.cost import cost_rates
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse
from snac_gym.rollout.episode import episode_length
from snac_gym.tasks import TASKS

#: The UR10's ids, the paper's arm (tests/envs/test_ids.py checks every robot's).
ENV_IDS = [task.env_id for task in TASKS.values()]


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


def test_human_render_without_display_warns_on_the_first_step(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    env = gym.make(ENV_IDS[0], render_mode="human")  # the constructor works headless (check_env builds it)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # check_env builds, resets and renders a "human" env: all quiet
        env.reset(seed=0)
        assert env.render() is None
    with pytest.warns(UserWarning, match="needs a display"):
        env.step(env.action_space.sample() * 0)  # the first frame a "human" env draws in an episode
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once
        env.step(env.action_space.sample() * 0)
    env.close()


def _rollout(env_id, seed, actions, **kwargs):
    return _run(gym.make(env_id, **kwargs), seed, actions)


def _run(env, seed, actions):
    """:func:`_rollout` on ``env``, a fresh env (never reset or stepped), which it closes."""
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
def test_an_env_without_a_render_mode_loads_no_meshes_and_moves_bit_for_bit_as_a_drawn_one(env_id):
    import pybullet as p

    env = gym.make(env_id)
    actions = _actions(env, 120, scale=1.0)
    base = env.unwrapped
    assert p.getVisualShapeData(base.arm.body.body, physicsClientId=base.sim.client) == ()
    drawn = gym.make(env_id, render_mode="rgb_array", render_width=32, render_height=32)
    assert len(p.getVisualShapeData(drawn.unwrapped.arm.body.body, physicsClientId=drawn.unwrapped.sim.client)) > 0
    if not os.environ.get("DISPLAY"):  # "human" with no display draws nothing: no meshes either
        shown_nowhere = gym.make(env_id, render_mode="human").unwrapped
        assert p.getVisualShapeData(shown_nowhere.arm.body.body, physicsClientId=shown_nowhere.sim.client) == ()
        shown_nowhere.close()
    # the episodes on these two fresh envs (a drawn one's construction loads its meshes: 0.2 s, once)
    plain = _run(env, 5, actions)
    shown = _run(drawn, 5, actions)
    np.testing.assert_array_equal(plain[0], shown[0])
    np.testing.assert_array_equal(plain[1], shown[1])


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
    np.testing.assert_allclose(base.kinematics.base_to_world(fields.x), base.arm.body.ee_world_position(), atol=1e-6)
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
    env = gym.make(env_id, max_episode_steps=3)
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]
    constructed = type(env.unwrapped)(max_steps=3, physics="kinematic")  # a constructed env truncates itself
    constructed.reset(seed=0)
    assert [constructed.step(np.zeros(6))[3] for _ in range(3)] == [False, False, True]


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
        (
            "snac_gym/UR10EllipseTrack-v0",
            {"ellipse": {"centre": [-0.7, 0, 0.5], "radius": 1.5}},
            "outside the reachable",
        ),
        (
            "snac_gym/UR10EllipseTrack-v0",
            {"ellipse": {"center": [-0.7, 0, 0.5], "radius": 0.1}},
            "unknown ellipse keys",
        ),
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
        gym.make("snac_gym/UR10Reach-v0", reward_type="bogus")
    with pytest.raises(ValueError, match="action_type"):
        gym.make("snac_gym/UR10Reach-v0", action_type="torque")
    with pytest.raises(ValueError, match="observation_dtype"):
        gym.make("snac_gym/UR10Reach-v0", observation_dtype=np.int32)
    with pytest.raises(ValueError, match="n_substeps"):
        gym.make("snac_gym/UR10Reach-v0", n_substeps=0)
    with pytest.raises(ValueError, match="unknown robot"):
        gym.make("snac_gym/UR10Reach-v0", robot="kuka")


def test_step_before_reset_is_an_error():
    env = gym.make("snac_gym/UR10Reach-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))


def test_other_ur_arms_run_through_the_same_code():
    env = gym.make("snac_gym/UR5Reach-v0")
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    assert base.kinematics.robot == "ur5" and obs.shape == (base.obs_layout.size,)
    assert base.sample_space.contains(base.reference.target)
    obs, *_ = env.step(np.zeros(6))
    np.testing.assert_allclose(base.kinematics.base_to_world(obs[12:15]), base.arm.body.ee_world_position(), atol=1e-6)


def test_env_docstrings_document_every_section():
    for env_id in ENV_IDS:
        doc = gym.spec(env_id).entry_point
        cls = gym.make(env_id).unwrapped.__class__
        for section in (
            "## Observation Space",
            "## Action Space",
            "## Episode End",
            "## Arguments",
            "## Version History",
        ):
            assert section in cls.__doc__, (doc, section)


# -- conventions and the learner options ---------------------------------------------------------

LEARNER = dict(
    action_type="normalized", observation_dtype=np.float32, reward_type="shaped", finite_observation_bounds=True
)


@pytest.mark.parametrize("kwargs", [{}, LEARNER], ids=["defaults", "learner"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_with_defaults_headless(env_id, kwargs, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)  # the checker also builds render_mode="human"
    env = gym.make(env_id, **kwargs)
    check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_episode_length_comes_from_the_registration(env_id):
    default = gym.spec(env_id).max_episode_steps
    env = gym.make(env_id)
    assert default == env.unwrapped.default_max_steps  # 1000 (8 s) reach, 2500 (20 s) track
    assert env.spec.max_episode_steps == default and episode_length(env) == default
    env = gym.make(env_id, max_episode_steps=4)
    assert env.spec.max_episode_steps == 4 and episode_length(env) == 4
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[3] for _ in range(4)]
    assert flags == [False, False, False, True]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_max_steps_under_gym_make_is_deprecated_and_no_hook_lengthens_the_time_limit(env_id):
    default = gym.spec(env_id).max_episode_steps
    assert gym.spec(env_id).additional_wrappers == ()  # no episode-length hook, a plain EnvSpec
    with pytest.warns(DeprecationWarning, match=r"max_steps=4\) is deprecated: pass max_episode_steps=4"):
        env = gym.make(env_id, max_steps=4, physics="kinematic")
    env.reset(seed=0)
    assert [env.step(np.zeros(6))[3] for _ in range(4)] == [False, False, False, True]  # the env truncates itself
    with pytest.warns(DeprecationWarning):
        env = gym.make(env_id, max_steps=default + 2, physics="kinematic")
    assert env.spec.max_episode_steps == default  # the registration's TimeLimit stays


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_episodes_longer_than_the_registered_one(env_id):
    default = gym.spec(env_id).max_episode_steps
    for kwargs in ({"max_episode_steps": default + 2}, {"max_episode_steps": default + 2, "physics": "kinematic"}):
        env = gym.make(env_id, **kwargs)
        assert env.spec.max_episode_steps == default + 2
        env.reset(seed=0)
        truncated = [env.step(np.zeros(6))[3] for _ in range(default + 2)]
        assert not any(truncated[:-1]) and truncated[-1]
        env.close()


@pytest.mark.parametrize("kwargs", [{}, LEARNER], ids=["defaults", "learner"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_observation_bounds_are_finite_where_physics_gives_them(env_id, kwargs):
    env = gym.make(env_id, max_episode_steps=150, **{"finite_observation_bounds": True, **kwargs})
    space, layout = env.observation_space, env.unwrapped.obs_layout
    finite = np.isfinite(space.low) & np.isfinite(space.high)
    assert not finite[layout.slices["qdot"]].any() and finite.sum() == layout.size - 6
    env.action_space.seed(0)
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        assert space.contains(obs)
        for _ in range(150):  # full-speed random actions, joints driven into their limits
            obs, *_ = env.step(env.action_space.sample())
            assert space.contains(obs), obs
    env.close()
    assert np.isinf(gym.make(env_id).observation_space.high).all()  # default: ±inf, as the real-robot env


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_float32_observations_are_the_float64_ones_rounded(env_id):
    env = gym.make(env_id)
    actions = _actions(env, 30)
    obs64, rewards64, _ = _rollout(env_id, 4, actions)
    obs32, rewards32, _ = _rollout(env_id, 4, actions, observation_dtype=np.float32)
    assert (
        obs32.dtype == np.float32
        and gym.make(env_id, observation_dtype="float32").observation_space.dtype == np.float32
    )
    np.testing.assert_array_equal(obs32, obs64.astype(np.float32))
    np.testing.assert_array_equal(rewards32, rewards64)


def test_normalized_actions_scale_to_the_velocity_limits():
    env = gym.make("snac_gym/UR10Reach-v0", action_type="normalized")
    limits = env.unwrapped.velocity_limits
    assert env.action_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, -1.0)
    np.testing.assert_array_equal(env.action_space.high, 1.0)
    env.reset(seed=0)
    env.action_space.seed(1)
    for _ in range(5):
        a = env.action_space.sample()
        *_, info = env.step(a)
        np.testing.assert_allclose(info["command"], a.astype(np.float64) * limits, rtol=1e-15)
    *_, info = env.step(np.full(6, 3.0))  # clipped to [-1, 1]
    np.testing.assert_array_equal(info["command"], limits)
    # the same command as rad/s gives the same rollout
    actions = _actions(env, 20)
    normalized = _rollout("snac_gym/UR10Reach-v0", 2, actions, action_type="normalized")
    velocity = _rollout("snac_gym/UR10Reach-v0", 2, [a.astype(np.float64) * limits for a in actions])
    np.testing.assert_array_equal(normalized[0], velocity[0])
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0, 0, 0, 0], dtype=np.float32))


@pytest.mark.parametrize("action_type", ["velocity", "normalized"])
def test_shaped_reward_is_the_documented_formula(action_type):
    from snac_gym.ppo.envs import RewardSpec

    env = gym.make("snac_gym/UR10EllipseTrack-v0", reward_type="shaped", action_type=action_type)
    limits = env.unwrapped.velocity_limits
    env.reset(seed=3)
    for action in _actions(env, 25, scale=1.5):
        _, reward, _, _, info = env.step(action)
        d = np.linalg.norm(info["error"])
        a = info["command"] / limits
        expected = -10.0 * d + np.exp(-((d / 0.01) ** 2)) - 0.01 * np.sum(a**2)
        assert reward == pytest.approx(expected, rel=1e-12, abs=1e-12)
        # the reward PPO trains on (its default weights, no smoothness term)
        assert reward == pytest.approx(RewardSpec().shaped(info["error_norm"], a, np.zeros(6)), rel=1e-12, abs=1e-12)


@pytest.mark.rl
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3_checker_has_no_warnings_for_the_learner_configuration(env_id):
    import warnings

    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id, **LEARNER)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_kinematic_physics_is_the_evaluators_engine_episode_for_episode(env_id):
    """physics="kinematic": θₖ₊₁ = θₖ + uₖΔt, the same observations and commands as simulate_kinematic."""
    from gymnasium.utils.env_checker import check_env

    from snac_gym.policies import make_policy
    from snac_gym.policies.base import PolicyContext
    from snac_gym.rollout import rollout, simulate_kinematic
    from snac_gym.tasks import Sample

    env = gym.make(env_id, physics="kinematic")
    check_env(env.unwrapped, skip_render_check=True)
    log = rollout(env, make_policy("snac", env), seed=5, steps=200)
    base = env.unwrapped
    q0 = log[[f"q_{j}" for j in range(6)]].to_numpy()[0]  # the start pose reset(seed=5) drew
    sample = Sample(base.task_name, 0, q0, base.reference)
    context = PolicyContext.from_env(env)
    batch = simulate_kinematic(context, lambda: make_policy("snac", context), [sample], 200, [5])
    np.testing.assert_allclose(log[[f"u_{j}" for j in range(6)]].to_numpy(), batch.commands[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.attrs["final_e"], batch.final_errors[0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="needs physics='pybullet'"):
        gym.make(env_id, physics="kinematic", render_mode="rgb_array")
    with pytest.raises(ValueError, match="physics must be one of"):
        gym.make(env_id, physics="bullet")


def test_pickling_records_every_constructor_keyword():
    import inspect
    import pickle

    from snac_gym.envs.core import URTaskEnv

    env = URTaskEnv(task="reach", physics="kinematic", max_steps=7, render_width=320)
    keywords = set(inspect.signature(URTaskEnv.__init__).parameters) - {"self", "backend"}
    assert set(env._init_kwargs) == keywords
    clone = pickle.loads(pickle.dumps(env))
    assert clone._init_kwargs == env._init_kwargs and clone.max_steps == 7 and clone._init_kwargs["render_width"] == 320
    env.close()
    clone.close()
