"""The batched kinematic vector env against a SyncVectorEnv of single kinematic envs, episode for episode."""

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs.vector import URTaskVectorEnv
from snac_gym.model.kinematics import Kinematics, PositionChain
from snac_gym.physics.scene import PATH_COLOUR
from snac_gym.tasks import TASKS

ENV_IDS = [task.env_id for task in TASKS.values()]  # the UR10's; test_a_seven_joint_arm_matches_too runs a Panda


@pytest.mark.parametrize("robot", ["ur3", "ur5", "ur10", "panda", "xarm7"])
def test_position_chain_is_pinocchio(robot):
    kinematics = Kinematics(robot)
    qs = np.random.default_rng(0).uniform(-2 * np.pi, 2 * np.pi, size=(64, kinematics.n_joints))
    expected = np.array([kinematics.forward(q) for q in qs])
    np.testing.assert_allclose(PositionChain.from_kinematics(kinematics).forward(qs), expected, rtol=0, atol=1e-12)


def _pair(env_id, count, **kwargs):
    vector = gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point", **kwargs)
    # The vector env takes max_steps itself; under gym.make (the sync sub-envs) it is max_episode_steps.
    single = {("max_episode_steps" if key == "max_steps" else key): value for key, value in kwargs.items()}
    sync = gym.make_vec(env_id, num_envs=count, vectorization_mode="sync", physics="kinematic", **single)
    return vector, sync


def _assert_infos_close(got, want, path="infos"):
    assert sorted(got) == sorted(want), path
    for key, value in want.items():
        if isinstance(value, dict):
            _assert_infos_close(got[key], value, f"{path}[{key!r}]")
        elif value.dtype == object:
            for a, b in zip(got[key], value, strict=True):
                assert (a is None and b is None) or np.allclose(a, b, rtol=0, atol=1e-12), f"{path}[{key!r}]"
        elif value.dtype == bool:
            np.testing.assert_array_equal(got[key], value, err_msg=f"{path}[{key!r}]")
        else:
            assert got[key].dtype == value.dtype and got[key].shape == value.shape, f"{path}[{key!r}]"
            np.testing.assert_allclose(got[key], value, rtol=1e-12, atol=1e-12, err_msg=f"{path}[{key!r}]")


def _assert_step_close(got, want, tol):
    (obs, reward, terminated, truncated, infos), (obs_w, reward_w, terminated_w, truncated_w, infos_w) = got, want
    assert obs.dtype == obs_w.dtype and obs.shape == obs_w.shape
    np.testing.assert_allclose(obs, obs_w, rtol=tol, atol=tol)
    np.testing.assert_allclose(reward, reward_w, rtol=1e-12, atol=1e-10)
    np.testing.assert_array_equal(terminated, terminated_w)
    np.testing.assert_array_equal(truncated, truncated_w)
    _assert_infos_close(infos, infos_w)


CASES = [
    # Short episodes and a wide success band, so that truncations and terminations come at
    # different steps in different sub-envs and autoreset runs many times.
    {"max_steps": 7},
    {"max_steps": 9, "reward_type": "shaped", "action_type": "normalized", "observation_dtype": np.float32},
    {"max_steps": 12, "reward_type": "sparse", "terminate_on_success": True, "success_tolerance": 0.4},
]


@pytest.mark.parametrize("kwargs", CASES, ids=["dense", "shaped-normalized-f32", "sparse-terminate"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vector_env_is_the_single_kinematic_env_episode_for_episode(env_id, kwargs):
    count = 3
    vector, sync = _pair(env_id, count, **kwargs)
    assert vector.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    assert vector.observation_space == sync.observation_space and vector.action_space == sync.action_space
    tol = 1e-6 if kwargs.get("observation_dtype") is np.float32 else 1e-12
    reset, reset_w = vector.reset(seed=11), sync.reset(seed=11)
    np.testing.assert_allclose(reset[0], reset_w[0], rtol=tol, atol=tol)
    _assert_infos_close(reset[1], reset_w[1])
    vector.action_space.seed(4)
    ended = np.zeros(count, dtype=bool)
    terminations = 0
    for _ in range(30):
        actions = vector.action_space.sample()
        got, want = vector.step(actions), sync.step(actions)
        _assert_step_close(got, want, tol)
        ended |= got[2] | got[3]
        terminations += int(got[2].sum())
    assert ended.all()  # every sub-env went through at least one autoreset
    assert terminations > 0 or not kwargs.get("terminate_on_success")
    mask = np.array([False, True, False])
    got, want = vector.reset(options={"reset_mask": mask}), sync.reset(options={"reset_mask": mask.copy()})
    np.testing.assert_allclose(got[0], want[0], rtol=tol, atol=tol)
    _assert_infos_close(got[1], want[1])
    _assert_step_close(vector.step(actions), sync.step(actions), tol)


def test_terminated_and_truncated_sub_envs_are_reset_on_the_next_step_only():
    env = gym.make_vec("snac_gym/UR10Reach-v0", num_envs=2, vectorization_mode="vector_entry_point", max_steps=2)
    obs, _ = env.reset(seed=0)
    zero = np.zeros((2, 6))
    first = env.step(zero)
    _, _, _, truncated, _ = env.step(zero)
    assert truncated.all()
    obs, reward, terminated, truncated, infos = env.step(np.full((2, 6), np.nan))  # ignored: both autoreset
    assert not (terminated | truncated).any() and np.all(reward == 0.0)
    assert "q0" in infos and "cost_error" not in infos and np.all(infos["t"] == 0.0)
    np.testing.assert_array_equal(obs[:, :6], infos["q0"])
    assert not np.array_equal(obs, first[0])
    with pytest.raises(ValueError, match="sub-env 1 contains NaN"):
        env.step(np.array([[0.0] * 6, [np.nan] * 6]))


def test_registered_length_and_options_reach_every_sub_env():
    env = gym.make_vec("snac_gym/UR10EllipseTrack-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert env.unwrapped.max_episode_steps == gym.spec("snac_gym/UR10EllipseTrack-v0").max_episode_steps
    options = TASKS["track"].demo_options()
    obs, infos = env.reset(options=options)
    np.testing.assert_array_equal(obs[0], obs[1])
    np.testing.assert_allclose(infos["q0"][0], options["q0"])
    single = gym.make("snac_gym/UR10EllipseTrack-v0", physics="kinematic")
    np.testing.assert_allclose(obs[0], single.reset(options=options)[0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_batches_lie_in_the_batched_spaces(env_id):
    env = gym.make_vec(
        env_id,
        num_envs=16,
        vectorization_mode="vector_entry_point",
        finite_observation_bounds=True,
        action_type="normalized",
        observation_dtype=np.float32,
    )
    obs, _ = env.reset(seed=1)
    assert env.observation_space.contains(obs) and env.observation_space.shape == (16, 27)
    env.action_space.seed(0)
    for _ in range(20):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert reward.dtype == np.float64 and terminated.dtype == truncated.dtype == np.bool_


def test_only_position_tasks_get_a_vector_entry_point():
    from snac_gym.envs.vector import vector_env_supports
    from snac_gym.tasks.pose import PoseReachTask, PoseTrackTask

    assert all(vector_env_supports(task) for task in TASKS.values() if task.env_id in ENV_IDS)
    assert not vector_env_supports(PoseReachTask()) and not vector_env_supports(PoseTrackTask())


def test_a_seven_joint_arm_matches_too():
    vector, sync = _pair("snac_gym/PandaReach-v0", 2, max_steps=4)
    np.testing.assert_allclose(vector.reset(seed=2)[0], sync.reset(seed=2)[0], rtol=0, atol=1e-12)
    vector.action_space.seed(0)
    for _ in range(6):
        actions = vector.action_space.sample()
        _assert_step_close(vector.step(actions), sync.step(actions), 1e-12)


def test_bad_arguments_are_refused():
    env_id = "snac_gym/UR10Reach-v0"
    with pytest.raises(ValueError, match="kinematic model only"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", physics="pybullet")
    with pytest.raises(ValueError, match="renders render_mode='rgb_array'"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="human")
    with pytest.raises(ValueError, match="num_envs"):
        gym.make_vec(env_id, num_envs=0, vectorization_mode="vector_entry_point")
    with pytest.raises(TypeError):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", colour="red")
    with pytest.raises(ValueError, match="reward_type"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", reward_type="huge")
    env = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    assert isinstance(env.unwrapped, URTaskVectorEnv) and isinstance(env, gym.vector.VectorEnv)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 6)))
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(options={"reset_mask": np.zeros(2, dtype=bool)})


def test_gym_make_keeps_pybullet_and_its_episode_length():
    env = gym.make("snac_gym/UR10Reach-v0", max_episode_steps=1500)
    assert env.unwrapped.physics == "pybullet" and env.spec.max_episode_steps == 1500
    env.close()


def test_the_vector_env_renders_its_first_episode_as_the_single_env_draws_it():
    """make_vec(..., render_mode="rgb_array").render() is the frame of sub-env 0: the single env, reset with the
    same seed and given the same commands, draws the same image (its arm set to the same joint angles)."""
    env_id = "snac_gym/UR10EllipseTrack-v0"
    kwargs = {"render_width": 96, "render_height": 72}
    vector = gym.make_vec(
        env_id, num_envs=3, vectorization_mode="vector_entry_point", render_mode="rgb_array", **kwargs
    )
    single = gym.make(env_id, physics="kinematic", **kwargs)
    viewer = gym.make(env_id, render_mode="rgb_array", **kwargs)
    vector.reset(seed=4), single.reset(seed=4)
    commands = np.full((3, 6), 0.2)
    for _ in range(30):
        vector.step(commands)
        single.step(commands[0])
    frame = vector.render()
    assert frame.shape == (72, 96, 3) and frame.dtype == np.uint8
    base = viewer.unwrapped
    viewer.reset(seed=4)
    base.reference, base.steps = single.unwrapped.reference, single.unwrapped.steps
    base.arm.restore(*single.unwrapped.arm.joint_state(), np.zeros(6))
    base._frame = None
    np.testing.assert_array_equal(frame, viewer.render())
    vector.step(np.full((3, 6), -0.5))
    later = vector.render()
    assert not np.array_equal(frame, later)  # the frame follows the episode
    path = np.array(PATH_COLOUR[:3]) * 255
    for image in (frame, later):  # the ellipse's markers stay drawn from one frame to the next
        assert (np.abs(image.astype(int) - path) <= 40).all(-1).sum() > 5
    vector.close(), single.close(), viewer.close()
