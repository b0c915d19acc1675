"""Frames people watch: framing, what is drawn, and real-time playback (videos)."""

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.physics.scene import PATH_COLOUR, TARGET_COLOUR, project
from snac_gym.tasks import TASKS

SIZE = 160


def _resolved_rate(base, obs, rng):
    """A wandering closed loop: towards the reference, with noise, so the links sweep the workspace."""
    f = base.obs_layout.unpack(obs)
    u = np.linalg.pinv(base.kinematics.jacobian(f.q)) @ (f.xdot_d - 2.0 * f.e) + rng.normal(0, 0.3, 6)
    return np.clip(u, -base.velocity_limits, base.velocity_limits)


@pytest.mark.parametrize("task, width, height", [("reach", SIZE, SIZE), ("track", SIZE, SIZE), ("reach", 200, 120)])
def test_every_link_and_the_reference_stay_in_the_image_over_random_episodes(task, width, height):
    env = gym.make(TASKS[task].env_id, render_mode="rgb_array", render_width=width, render_height=height)
    base, rng = env.unwrapped, np.random.default_rng(0)
    env.reset(seed=0)
    env.render()
    scene = base._scene
    worst = np.inf
    for episode in range(4):
        obs, _ = env.reset(seed=episode)
        for step in range(400):
            obs, *_ = env.step(_resolved_rate(base, obs, rng))
            if step % 20 == 0:
                points = np.vstack(
                    [scene.link_origins(), base.kinematics.base_to_world(base.reference.position(base.time))]
                )
                pixels = project(points, scene.view, scene.projection, width, height)
                assert (pixels[:, 2] > 0).all()
                margin = np.minimum(pixels[:, :2], np.array([width, height]) - pixels[:, :2]).min()
                worst = min(worst, margin)
                assert margin > 0, f"{task} episode {episode} step {step}: a link at {pixels[:, :2].round()} is cut off"
    env.close()
    assert worst > 2  # pixels between the nearest link and the image edge


def _pixels_like(image, colour, tolerance=40):
    target = np.array(colour[:3]) * 255
    return int((np.abs(image.astype(int) - target) <= tolerance).all(axis=-1).sum())


def test_frames_show_the_target_the_path_and_play_in_real_time():
    env = gym.make("snac_gym/UR10EllipseTrack-v0", render_mode="rgb_array", render_width=SIZE, render_height=SIZE)
    base = env.unwrapped
    assert base.metadata["render_fps"] == round(1 / base.dt) == 125  # one frame per control step: real time
    assert base.render_every == 5  # a new image 25 times a second
    env.reset(seed=0, options=base.task.demo_options())
    first = env.render()
    assert first.shape == (SIZE, SIZE, 3) and first.dtype == np.uint8
    assert _pixels_like(first, TARGET_COLOUR) > 5 and _pixels_like(first, PATH_COLOUR) > 10
    frames = []
    for _ in range(10):
        env.step(np.full(6, 0.5))
        frames.append(env.render())
    changed = [not np.array_equal(a, b) for a, b in zip([first] + frames[:-1], frames)]
    assert changed == [False, False, False, False, True] * 2  # images at steps 5 and 10, repeats between
    reach = gym.make("snac_gym/UR10Reach-v0", render_mode="rgb_array", render_width=SIZE, render_height=SIZE)
    reach.reset(seed=0)
    assert _pixels_like(reach.render(), PATH_COLOUR) == 0  # a fixed target has no path
    with pytest.raises(ValueError, match="render_every must be a positive"):
        gym.make("snac_gym/UR10Reach-v0", render_mode="rgb_array", render_every=0)
    env.close(), reach.close()
