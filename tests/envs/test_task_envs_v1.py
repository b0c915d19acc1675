"""The -v1 ids: RL-ready defaults (normalized float32 actions, float32 observations in finite bounds).

Both checkers pass every registered -v1 id at its defaults without a single warning, headless; the
-v0 ids keep their physical units; ``make_policy`` drives a -v1 env through its scaling; the README's
usage snippet reaches the target on the default id.
"""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs import ENV_IDS, ENV_IDS_V1, GOAL_ENV_IDS, GOAL_ENV_IDS_V1, REGISTERED_IDS, V1_DEFAULTS
from snac_gym.envs.task_envs import PoseReachEnv
from snac_gym.policies import EnvUnitsPolicy, PolicyContext, make_policy

ROOT = Path(__file__).resolve().parents[2]
V1_IDS = sorted(ENV_IDS_V1) + sorted(GOAL_ENV_IDS_V1)


def _checked_quietly(env_id: str) -> list[warnings.WarningMessage]:
    """Both checkers on ``env_id`` at its defaults; every warning they (or the env) raised."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id)
        check_env(env.unwrapped)
        sb3_env_checker = pytest.importorskip("stable_baselines3.common.env_checker")
        # SB3 reads compute_reward on the env it is given, which Gymnasium 1.x's wrappers do not forward:
        # a goal env is checked unwrapped (as SB3's HER itself reaches it).
        goal = isinstance(env.observation_space, gym.spaces.Dict)
        with contextlib.redirect_stdout(io.StringIO()):  # SB3 prints that it detected a GoalEnv
            sb3_env_checker.check_env(env.unwrapped if goal else env)
        env.close()
    return list(caught)


def test_every_id_has_a_v1_and_keeps_its_v0():
    assert len(V1_IDS) >= 54
    assert {env_id.replace("-v0", "-v1") for env_id in [*ENV_IDS, *GOAL_ENV_IDS]} == set(V1_IDS)
    assert all(env_id in gym.registry for env_id in [*ENV_IDS, *GOAL_ENV_IDS, *V1_IDS])
    assert all(REGISTERED_IDS[env_id].version == 1 for env_id in V1_IDS)
    assert gym.spec("snac_gym/UR10Reach-v1").kwargs == {"robot": "ur10", **V1_DEFAULTS}


@pytest.mark.slow(seconds=30)
@pytest.mark.parametrize("env_id", V1_IDS)
def test_both_checkers_pass_every_v1_id_without_a_warning(env_id, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)  # Gymnasium's checker also builds and renders render_mode="human"
    caught = _checked_quietly(env_id)
    for warning in caught:
        print(f"{warning.category.__name__}: {warning.message} ({warning.filename}:{warning.lineno})")
    assert not caught, f"{env_id}: {len(caught)} warnings (printed above)"


@pytest.mark.parametrize("env_id", ["snac_gym/UR10Reach-v1", "snac_gym/PandaEllipseTrack-v1"])
def test_v1_spaces_are_normalized_float32_and_finite(env_id):
    env = gym.make(env_id)
    base = env.unwrapped
    action, observation = env.action_space, env.observation_space
    assert action.dtype == np.float32 and np.all(action.low == -1) and np.all(action.high == 1)
    assert (
        observation.dtype == np.float32
        and np.all(np.isfinite(observation.low))
        and np.all(np.isfinite(observation.high))
    )
    slices = base.obs_layout.slices
    k = base.kinematics
    np.testing.assert_allclose(observation.high[slices["qdot"]], k.velocity_limits.astype(np.float32))
    np.testing.assert_allclose(observation.high[slices["q"]], (k.upper_limits + 0.1).astype(np.float32))
    np.testing.assert_allclose(observation.low[slices["q"]], (k.lower_limits - 0.1).astype(np.float32))
    assert base.finite_observation_bounds == "clip"
    env.close()


def test_v0_keeps_its_physical_units_and_is_not_called_out_of_date():
    # Gymnasium calls an id with a newer version "out of date"; a -v0 id is the physical-units env, not
    # deprecated: importing snac_gym silences that notice for its -v0 ids (a fresh interpreter, every warning on).
    code = "import gymnasium as gym, snac_gym; gym.make('snac_gym/UR10Reach-v0', physics='kinematic')"
    done = subprocess.run([sys.executable, "-W", "always", "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "out of date" not in done.stderr, done.stderr
    env = gym.make("snac_gym/UR10Reach-v0")
    assert env.action_space.dtype == np.float64
    np.testing.assert_array_equal(env.action_space.high, env.unwrapped.velocity_limits)
    assert env.observation_space.dtype == np.float64 and np.all(np.isinf(env.observation_space.high))
    env.close()
    goal = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic")
    assert goal.action_space.dtype == np.float64 and np.isinf(goal.observation_space["observation"].high).any()
    goal.close()


def test_a_v1_env_is_the_v0_env_with_its_arguments():
    """-v1 changes defaults only: the v0 id with V1_DEFAULTS gives the same episode, and -v1 takes them back."""
    actions = np.random.default_rng(3).uniform(-1, 1, size=(30, 6)).astype(np.float32)
    runs = []
    for env_id, kwargs in (("snac_gym/UR10Reach-v1", {}), ("snac_gym/UR10Reach-v0", dict(V1_DEFAULTS))):
        env = gym.make(env_id, physics="kinematic", **kwargs)
        obs = [env.reset(seed=5)[0]] + [env.step(a)[0] for a in actions]
        runs.append(np.array(obs))
        env.close()
    np.testing.assert_array_equal(*runs)
    env = gym.make(
        "snac_gym/UR10Reach-v1", action_type="velocity", observation_dtype=np.float64, finite_observation_bounds=False
    )
    assert env.action_space.dtype == np.float64 and np.all(np.isinf(env.observation_space.high))
    env.close()


def test_the_observation_is_clipped_into_its_bounds():
    env = gym.make("snac_gym/UR10Reach-v1")
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    low, high = base.observation_clip
    wild = np.where(np.arange(len(low)) % 2, 10 * high, 10 * low)  # every field far outside
    out = base._output(wild)
    assert out.dtype == np.float32 and env.observation_space.contains(out)
    np.testing.assert_array_equal(out, np.clip(wild, low, high).astype(np.float32))
    rng = np.random.default_rng(0)
    for _ in range(200):  # full-speed random commands, the joints driven into their limits
        obs, *_ = env.step(np.sign(rng.uniform(-1, 1, 6)).astype(np.float32))
        assert env.observation_space.contains(obs)
    env.close()


def test_the_vector_env_of_a_v1_id_has_its_spaces_and_bounds():
    vector = gym.make_vec("snac_gym/UR10Reach-v1", 3, vectorization_mode="vector_entry_point")
    single = gym.make("snac_gym/UR10Reach-v1", physics="kinematic")
    assert vector.single_observation_space == single.observation_space
    assert vector.single_action_space == single.action_space
    obs, _ = vector.reset(seed=0)
    first, _ = single.reset(seed=0)
    assert obs.dtype == np.float32 and vector.observation_space.contains(obs)
    np.testing.assert_allclose(obs[0], first, atol=1e-6)
    obs, *_ = vector.step(np.ones((3, 6), dtype=np.float32))
    assert vector.observation_space.contains(obs)
    vector.close()
    single.close()


def test_the_pose_tasks_v1_bounds_hold_their_orientations():
    """A pose task's rotation vectors (norm ≤ π) fit their bounds although the arm's reach is shorter
    (the UR10: 1.88 m)."""
    env = PoseReachEnv(robot="ur10", physics="kinematic", **V1_DEFAULTS)
    check_env(env, skip_render_check=True)
    rng = np.random.default_rng(1)
    largest = 0.0
    for seed in range(5):
        obs, _ = env.reset(seed=seed)
        assert env.observation_space.contains(obs)
        for _ in range(20):
            obs, *_ = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
            assert env.observation_space.contains(obs)
            rotation = env.obs_layout.unpack(obs).x[3:]
            assert np.linalg.norm(rotation) <= np.pi + 1e-5
            largest = max(largest, float(np.abs(rotation).max()))
    assert largest > 1.88  # past ρ, the bound the orientations had before
    env.close()


def test_a_wrong_robot_on_a_v1_id_names_the_v1_id():
    with pytest.raises(ValueError, match=re.escape("gym.make('snac_gym/PandaReach-v1')")):
        gym.make("snac_gym/UR10Reach-v1", robot="panda")


# -- make_policy on a -v1 env ----------------------------------------------------------------------------
@pytest.mark.parametrize("controller", ["snac", "dls"])
def test_make_policy_maps_the_v1_scaling_both_ways(controller):
    """The controller sees float64 observations and returns rad/s; the env gets a = u / ū, float32."""
    v1 = gym.make("snac_gym/UR10Reach-v1", physics="kinematic")
    v0 = gym.make("snac_gym/UR10Reach-v0", physics="kinematic")
    wrapped, plain = make_policy(controller, v1), make_policy(controller, v0)
    assert isinstance(wrapped, EnvUnitsPolicy) and not isinstance(plain, EnvUnitsPolicy)
    assert type(wrapped.policy) is type(plain)
    obs1, _ = v1.reset(seed=2)
    obs0, _ = v0.reset(seed=2)
    wrapped.reset(seed=2)
    plain.reset(seed=2)
    for _ in range(100):
        a, u = wrapped.act(obs1), plain.act(obs0)
        assert a.dtype == np.float32 and v1.action_space.contains(a)
        # the same command, up to the float32 rounding of the observation and of a
        np.testing.assert_allclose(
            wrapped.to_command(a), np.clip(u, -v0.unwrapped.velocity_limits, v0.unwrapped.velocity_limits), atol=1e-4
        )
        obs1, *_, info1 = v1.step(a)
        obs0, *_, info0 = v0.step(u)
    np.testing.assert_allclose(info1["error"], info0["error"], atol=1e-5)
    assert wrapped.internals is wrapped.policy.internals
    v1.close()
    v0.close()


def test_make_policy_leaves_physical_units_unwrapped():
    env = gym.make("snac_gym/UR10Reach-v0", physics="kinematic")
    context = PolicyContext.from_env(env)
    assert not isinstance(make_policy("dls", context), EnvUnitsPolicy)  # the evaluator's way
    assert not isinstance(make_policy("dls", env), EnvUnitsPolicy)
    v1 = gym.make("snac_gym/UR10Reach-v1", physics="kinematic")
    assert not isinstance(make_policy("dls", PolicyContext.from_env(v1)), EnvUnitsPolicy)
    env.close()
    v1.close()


def test_the_wrapped_batch_protocol_is_scaled_too():
    v1 = gym.make("snac_gym/UR10Reach-v1", physics="kinematic")
    wrapped = make_policy("snac", v1)
    obs, _ = v1.reset(seed=0)
    if not callable(getattr(wrapped.policy, "act_batch", None)):
        pytest.skip("snac has no batch protocol")
    wrapped.reset_batch([0, 1])
    batch = wrapped.act_batch(np.stack([obs, obs]))
    assert batch.dtype == np.float32 and batch.shape == (2, 6) and np.all(np.abs(batch) <= 1)
    v1.close()


# -- the README ------------------------------------------------------------------------------------------
def _usage_snippet() -> str:
    """The README's usage snippet (the first Python block under "## Usage")."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    usage = text.split("## Usage", 1)[-1]
    match = re.search(r"```python\n(.*?)```", usage, re.DOTALL)
    assert match, "README.md has no Python block under ## Usage"
    return match.group(1)


@pytest.mark.slow(seconds=3)
def test_the_readme_usage_snippet_reaches_the_target_on_the_v1_id():
    snippet = _usage_snippet()
    assert 'gym.make("snac_gym/UR10Reach-v1")' in snippet
    namespace: dict = {"__name__": "__main__"}
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        exec(compile(snippet, "README.md usage", "exec"), namespace)
    env, info = namespace["env"], namespace["info"]
    assert env.spec.id == "snac_gym/UR10Reach-v1" and env.action_space.dtype == np.float32
    assert info["is_success"] and info["error_norm"] <= env.unwrapped.success_tolerance
    assert "success: True" in printed.getvalue()
    env.close()
