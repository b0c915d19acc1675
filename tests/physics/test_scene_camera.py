"""Camera options (panda-gym's names) on every env, and default frames that show the arm and the target."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.scene import CameraOptions, fit_camera, project


@pytest.mark.parametrize(("yaw", "pitch"), [(0.0, 0.0), (90.0, -30.0), (45.0, -25.0), (-120.0, 40.0)])
def test_yaw_and_pitch_follow_pybullets_convention(yaw, pitch):
    """The camera's eye against PyBullet's own view matrix for the same yaw, pitch, distance and target."""
    target, distance = np.array([0.3, -0.2, 0.4]), 1.7
    camera = fit_camera(
        np.zeros((2, 3)) + target,
        Kinematics("ur10"),
        320,
        240,
        CameraOptions(distance=distance, yaw=yaw, pitch=pitch, target=tuple(target)),
    )
    view = np.array(p.computeViewMatrixFromYawPitchRoll(target.tolist(), distance, yaw, pitch, 0.0, 2)).reshape(4, 4).T
    eye = -view[:3, :3].T @ view[:3, 3]
    np.testing.assert_allclose(camera.eye, eye, atol=1e-6)
    np.testing.assert_allclose(
        np.array(camera.view), np.array(p.computeViewMatrix(eye.tolist(), target.tolist(), [0, 0, 1])), atol=1e-5
    )


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"render_pitch": 90}, r"render_pitch \(degrees\) must be a finite number in \[-89, 89\], got 90"),
        ({"render_distance": -1.0}, r"render_distance \(m\) must be a finite number in \(0, 20\], got -1.0"),
        ({"render_target_position": (0, np.nan, 0)}, r"render_target_position \(m\) must be finite"),
        ({"render_target_position": (0, 0)}, r"render_target_position \(m\) must have shape \(3,\)"),
        ({"render_yaw": "30"}, r"render_yaw \(degrees\) must be a real number"),
    ],
)
def test_meaningless_camera_options_are_refused_when_the_env_is_made(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("snac_gym/UR10Reach-v0", **kwargs)


@pytest.mark.parametrize("physics", ["pybullet", "mujoco"])
def test_camera_options_move_the_camera_in_both_engines(physics):
    if physics == "mujoco":
        pytest.importorskip("mujoco")
    frames = []
    for options in (
        {},
        {"render_distance": 2.6, "render_yaw": 20, "render_pitch": -35, "render_target_position": (0.4, 0.4, 0.4)},
    ):
        env = gym.make(
            "snac_gym/UR10Reach-v0",
            physics=physics,
            render_mode="rgb_array",
            render_width=96,
            render_height=64,
            **options,
        )
        env.reset(seed=0)
        frames.append(env.render())
        scene = env.unwrapped._scene
        env.close()
        if options:
            view = np.array(scene.view).reshape(4, 4).T
            eye = -view[:3, :3].T @ view[:3, 3]
            expected = (
                np.array(p.computeViewMatrixFromYawPitchRoll([0.4, 0.4, 0.4], 2.6, 20, -35, 0, 2)).reshape(4, 4).T
            )
            np.testing.assert_allclose(eye, -expected[:3, :3].T @ expected[:3, 3], atol=1e-6)
    assert frames[0].shape == frames[1].shape == (64, 96, 3) and np.abs(frames[0].astype(int) - frames[1]).mean() > 5


@pytest.mark.parametrize(
    "env_id",
    [
        "snac_gym/UR10Reach-v0",
        "snac_gym/UR3EllipseTrack-v0",
        "snac_gym/PandaReach-v0",
        "snac_gym/XArm7Reach-v0",
        "snac_gym/PandaReachGoalCoarse-v0",
    ],
)
def test_the_default_frame_shows_the_arm_and_the_target_on_unseen_episodes(env_id):
    """Every link origin and the target of episodes the framing did not use project inside the image."""
    env = gym.make(env_id, render_mode="rgb_array", render_width=160, render_height=120)
    base = env.unwrapped if hasattr(env.unwrapped, "_scene") else env.unwrapped.env  # the goal env wraps the task env
    for seed in range(101, 109):
        env.reset(seed=seed)
        env.render()
        scene = base._scene
        target = scene.kinematics.base_to_world(np.asarray(base.reference.position(base.time), dtype=float))
        points = np.vstack([scene.link_origins(), [target]])
        pixels = project(points, scene.view, scene.projection, 160, 120)
        assert np.all((pixels[:, 0] >= 0) & (pixels[:, 0] <= 160) & (pixels[:, 1] >= 0) & (pixels[:, 1] <= 120)), (
            seed,
            pixels,
        )
    env.close()
