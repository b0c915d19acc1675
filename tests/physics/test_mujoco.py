"""physics="mujoco": the same URDF in MuJoCo follows the kinematic model as PyBullet does, passes the
checker headless on every id, stops at joint limits, renders the PyBullet scene and pickles."""

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

pytest.importorskip("mujoco", reason="physics='mujoco' needs the mujoco extra")

import snac_gym  # noqa: E402
from snac_gym.apps.bench import run_tracking_study  # noqa: E402
from snac_gym.envs import GOAL_ENV_IDS  # noqa: E402
from snac_gym.physics import mujoco as mujoco_sim  # noqa: E402
from snac_gym.physics.scene import PATH_COLOUR, TARGET_COLOUR, project  # noqa: E402

#: How closely a simulated arm must follow the exact kinematic model θₖ₊₁ = θₖ + uₖΔt under the
#: smooth random command of :func:`snac_gym.apps.bench.random_command` (5 episodes of 1000 steps = 8 s):
#: the measured joint velocity within 0.02 rad/s of the command at every step (1 % of the UR10's
#: slowest limit), and the end effector within 2 mm of the kinematic model's after the last step.
#: Both engines meet it (docs/physics.md): PyBullet by 2.3x on the Panda's velocity and 1.6x on
#: the UR10's drift, MuJoCo by 10x or more.
VELOCITY_TOLERANCE = 0.02
DRIFT_TOLERANCE = 2e-3


@pytest.mark.parametrize("env_id", ["snac_gym/UR10Reach-v0", "snac_gym/PandaReach-v0"])
def test_mujoco_follows_the_kinematic_model_within_the_tolerance_pybullet_meets(env_id):
    rows = {row["physics"]: row for row in run_tracking_study(env_ids=(env_id,), commands=("smooth",), episodes=5)}
    for physics, row in rows.items():
        assert row["max_velocity_error"] <= VELOCITY_TOLERANCE, (physics, row)
        assert row["ee_drift"] <= DRIFT_TOLERANCE, (physics, row)
    for key in ("max_velocity_error", "max_joint_drift", "ee_drift"):  # the stiffer servo follows closer
        assert rows["mujoco"][key] < rows["pybullet"][key], key


@pytest.mark.slow(seconds=0.3)
@pytest.mark.parametrize("env_id", sorted(snac_gym.ENV_IDS) + sorted(GOAL_ENV_IDS))
def test_every_id_passes_check_env_headless_with_mujoco(env_id, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)  # the checker also builds render_mode="human"
    env = gym.make(env_id, physics="mujoco")
    check_env(env.unwrapped)
    env.close()


def test_observation_is_mujocos_own_end_effector_and_backend_is_the_deprecated_name():
    with pytest.warns(DeprecationWarning, match="physics='mujoco'"):
        env = gym.make("snac_gym/PandaEllipseTrack-v0", backend="mujoco")
    base, rng = env.unwrapped, np.random.default_rng(0)
    assert base.physics == "mujoco" and type(base.arm).__name__ == "MuJoCoArm"
    obs, _ = env.reset(seed=3)
    for _ in range(50):
        obs, *_ = env.step(rng.uniform(-0.5, 0.5, 7))
        x = base.obs_layout.unpack(obs).x
        np.testing.assert_allclose(base.kinematics.base_to_world(x), base.arm.ee_world_position(), atol=1e-9)
    env.close()


def test_a_joint_driven_into_its_limit_stops_there():
    env = gym.make("snac_gym/PandaReach-v0", physics="mujoco")
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    upper = base.kinematics.upper_limits[3]  # the elbow's, -0.07 rad
    u = np.zeros(7)
    u[3] = base.velocity_limits[3]
    for _ in range(200):  # 1.6 s at full speed: far past the limit without it
        obs, *_ = env.step(u)
    assert abs(obs[3] - upper) < 1e-3 and abs(obs[7 + 3]) < 1e-2
    env.close()


def test_a_pickled_episode_goes_on_identically():
    env = gym.make("snac_gym/UR10Reach-v0", physics="mujoco").unwrapped
    env.reset(seed=1)
    u = np.array([0.3, -0.2, 0.4, 0.1, -0.3, 0.2])
    for _ in range(20):
        env.step(u)
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(20):
        a, *_ = env.step(-u)
        b, *_ = copy.step(-u)
    np.testing.assert_allclose(a, b, atol=1e-6)  # restored at rest from θ, θ̇: the servo settles in 0.1 ms
    env.close(), copy.close()


# -- rendering ------------------------------------------------------------------------------------------
SIZE = 160


def _pixels_like(image, colour, tolerance=40):
    target = np.array(colour[:3]) * 255
    return int((np.abs(image.astype(int) - target) <= tolerance).all(axis=-1).sum())


def test_frames_show_the_pybullet_scene_through_the_same_camera():
    env = gym.make(
        "snac_gym/UR10EllipseTrack-v0", physics="mujoco", render_mode="rgb_array", render_width=SIZE, render_height=SIZE
    )
    peer = gym.make("snac_gym/UR10EllipseTrack-v0", render_mode="rgb_array", render_width=SIZE, render_height=SIZE)
    base = env.unwrapped
    options = base.task.demo_options()
    env.reset(seed=0, options=options), peer.reset(seed=0, options=options)
    first = env.render()
    assert first.shape == (SIZE, SIZE, 3) and first.dtype == np.uint8
    assert _pixels_like(first, TARGET_COLOUR) > 5 and _pixels_like(first, PATH_COLOUR) > 10
    np.testing.assert_allclose(base._scene.view, peer.unwrapped._scene.view, atol=1e-5)  # the same camera
    # The same target pixels (±2) in both engines' images: the same scene, drawn alike.
    mine, theirs = (
        np.argwhere((np.abs(im.astype(int) - np.array(TARGET_COLOUR[:3]) * 255) <= 40).all(-1)).mean(0)
        for im in (first, peer.render())
    )
    assert np.abs(mine - theirs).max() < 2
    frames = []
    for _ in range(10):
        env.step(np.full(6, 0.5))
        frames.append(env.render())
    assert [not np.array_equal(a, b) for a, b in zip([first] + frames[:-1], frames)] == [False] * 4 + [True] + [
        False
    ] * 4 + [True]
    env.close(), peer.close()


def test_every_link_stays_in_the_image_over_random_episodes():
    env = gym.make(
        "snac_gym/PandaEllipseTrack-v0", physics="mujoco", render_mode="rgb_array", render_width=200, render_height=120
    )
    base, rng = env.unwrapped, np.random.default_rng(0)
    env.reset(seed=0)
    env.render()
    scene = base._scene
    for episode in range(3):
        env.reset(seed=episode)
        for step in range(300):
            env.step(np.clip(rng.normal(0, 0.4, 7), -base.velocity_limits, base.velocity_limits))
            if step % 30 == 0:
                pixels = project(scene.link_origins(), scene.view, scene.projection, 200, 120)
                assert (pixels[:, 2] > 0).all()
                assert (pixels[:, :2] > 0).all() and (pixels[:, :2] < [200, 120]).all(), (episode, step)
    env.close()


def test_no_headless_opengl_is_one_clear_error(monkeypatch):
    def no_platform(name):
        raise ImportError(f"libraries of {name} not found")

    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(mujoco_sim, "_context_class", no_platform)
    with pytest.raises(
        RuntimeError,
        match=r"neither works here \(egl: ImportError: libraries of egl.*osmesa: "
        r"ImportError.*install libegl1.*libosmesa6",
    ):
        gym.make("snac_gym/UR10Reach-v0", physics="mujoco", render_mode="rgb_array")


def test_human_mode_warns_once_and_shows_nothing(monkeypatch):
    env = gym.make("snac_gym/UR10Reach-v0", physics="mujoco", render_mode="human")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=0)
        env.step(np.zeros(6))
    messages = [str(w.message) for w in caught if "render_mode='human'" in str(w.message)]
    assert len(messages) == 1 and "HumanRendering" in messages[0]
    env.close()
