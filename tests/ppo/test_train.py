"""The PPO baseline: a tiny training run through the CLI that saves, reloads and acts identically,
Ctrl-C and --resume, every load error of the ``ppo`` policy, and the shipped policies."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.ppo import MissingPolicyFileError, PolicyFile, PolicyFileError, PPOPolicy, shipped_model_path
from snac_gym.ppo.config import default_config_path, load_config, resolve_config
from snac_gym.ppo.features import FeatureSpec, feature_size, observation_features
from snac_gym.references import PAPER_Q0

ENV_OF_TASK = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}


def _independent_task_relative_command(policy, observations, action, scale):
    """``u = argmin ‖J u − v‖² + λ²‖u‖²`` by the normal equations ``(JᵀJ + λ²I) u = Jᵀv`` (not the
    ``Jᵀ(JJᵀ + λ²I)⁻¹`` form the package uses), with ``v = ẋ_d + s·k_max·(‖e‖ + 10⁻⁴)·a``, clipped to ±ū."""
    spec, layout = policy.model.features, policy.layout
    out = []
    for obs, a in zip(observations, action, strict=True):
        q, e, xdot_d = obs[layout.slices["q"]], obs[layout.slices["e"]], obs[layout.slices["xdot_d"]]
        jac = Kinematics("ur10").jacobian(q)
        v = xdot_d + scale * spec.gain_max * (np.linalg.norm(e) + 1e-4) * np.clip(a, -1, 1)
        u = np.linalg.solve(jac.T @ jac + spec.damping**2 * np.eye(6), jac.T @ v)
        out.append(np.clip(u, -policy.velocity_limits, policy.velocity_limits))
    return np.array(out)


def _observations(task, count=40, seed=5):
    """Observations of a short random-action episode of the task's env."""
    env = gym.make(ENV_OF_TASK[task], max_episode_steps=count)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs]
    for _ in range(count - 1):
        obs, *_ = env.step(rng.uniform(-0.3, 0.3, 6))
        out.append(obs)
    env.close()
    return np.array(out)


@pytest.fixture(scope="module")
def reach_env():
    env = gym.make(ENV_OF_TASK["reach"])
    yield env
    env.close()


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, tiny_ppo):
    """One tiny reach training run made by the CLI command."""
    tmp_path = tmp_path_factory.mktemp("ppo")
    config = tiny_ppo(tmp_path)
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app,
        [
            "train-ppo",
            "--task",
            "reach",
            "--timesteps",
            "64",
            "--seed",
            "3",
            "--out",
            str(out),
            "--config",
            str(config),
        ],
    )
    assert result.exit_code == 0, result.output
    return out, config, result.output


@pytest.mark.parametrize("missing", ["torch", "stable_baselines3"])
def test_train_ppo_without_the_rl_extra_names_it_in_one_line(tmp_path, monkeypatch, missing):
    monkeypatch.setitem(sys.modules, missing, None)  # `import missing` raises ImportError, as where it is not installed
    result = CliRunner().invoke(app, ["train-ppo", "--task", "reach", "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert result.output == (
        "error: train-ppo (stable-baselines3 and torch) needs the 'rl' extra: pip install -e \".[rl]\"\n"
    )
    assert not (tmp_path / "run").exists()


# -- training: save, reload, act identically ------------------------------------------------------
@pytest.mark.rl
def test_tiny_training_saves_everything_needed_to_reload(trained_run):
    out, _, output = trained_run
    assert "finished" in output and "best policy" in output
    for folder in ("checkpoint", "best"):
        for name in ("model.zip", "vecnormalize.pkl", "policy.npz"):
            assert (out / folder / name).is_file(), f"{folder}/{name} missing"
    config = json.loads((out / "config.json").read_text())
    assert config["seed"] == 3 and config["timesteps"] == 64 and config["versions"]["snac_gym"]
    state = json.loads((out / "state.json").read_text())
    assert state["status"] == "finished" and state["timesteps"] >= 64 and state["wall_time_s"] > 0
    evaluations = (out / "evaluations.csv").read_text().splitlines()
    header = "timesteps,wall_time_s,success_rate,success_rate_0.024s,success_rate_0.04s,mean_cost"
    assert evaluations[0].startswith(header)
    assert len(evaluations) >= 3
    assert (out / "logs" / "segment_0" / "progress.csv").stat().st_size > 0
    assert (out / "training_curves.png").stat().st_size > 1000
    metadata = PolicyFile.load(out / "best" / "policy.npz").metadata
    assert metadata["task"] == "reach" and metadata["seed"] == 3 and metadata["versions"]["snac_gym"]
    assert metadata["evaluation"]["timesteps"] == state["best"]["timesteps"]


@pytest.mark.rl
def test_reloaded_policy_acts_exactly_as_the_trained_model(trained_run, reach_env):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from snac_gym.ppo.train import make_training_env

    out, _, _ = trained_run
    model = PPO.load(out / "checkpoint" / "model.zip", device="cpu")
    config = json.loads((out / "config.json").read_text())
    venv = DummyVecEnv([lambda: make_training_env(config)])
    stats = VecNormalize.load(str(out / "checkpoint" / "vecnormalize.pkl"), venv)
    stats.training = False
    policy = make_policy("ppo", reach_env, model_path=out / "checkpoint" / "policy.npz")
    assert isinstance(policy, PPOPolicy)
    np.testing.assert_array_equal(policy.model.obs_mean, stats.obs_rms.mean)
    np.testing.assert_array_equal(policy.model.obs_var, stats.obs_rms.var)
    observations = _observations("reach")
    features = observation_features(observations, policy.layout, policy.model.features)
    actions, _ = model.predict(stats.normalize_obs(features), deterministic=True)
    assert actions.shape == (len(observations), 3)  # a task-space action
    expected = _independent_task_relative_command(policy, observations, actions, 1.0)
    commands = np.array([policy.act(obs) for obs in observations])
    np.testing.assert_allclose(commands, expected, rtol=0, atol=1e-5)
    np.testing.assert_allclose(policy.act_batch(observations), commands, rtol=0, atol=1e-9)
    # the statistics are frozen: acting changes nothing, and a second load acts bit for bit alike
    again = PPOPolicy(reach_env, model_path=out / "checkpoint" / "policy.npz")
    np.testing.assert_array_equal(np.array([again.act(obs) for obs in observations]), commands)
    np.testing.assert_array_equal(policy.model.obs_mean, stats.obs_rms.mean)


@pytest.mark.rl
def test_training_into_an_existing_run_or_resuming_nothing_is_refused(trained_run, tmp_path):
    out, config, _ = trained_run
    runner = CliRunner()
    again = runner.invoke(app, ["train-ppo", "--task", "reach", "--out", str(out), "--config", str(config)])
    assert again.exit_code == 2 and "already holds a training run" in again.output
    empty = runner.invoke(app, ["train-ppo", "--task", "reach", "--out", str(tmp_path / "none"), "--resume"])
    assert empty.exit_code == 2 and "no checkpoint" in empty.output
    other = runner.invoke(app, ["train-ppo", "--task", "track", "--out", str(out), "--resume"])
    assert other.exit_code == 2 and "trains task 'reach'" in other.output
    clone = out / "checkpoint" / "policy.npz"
    resumed = runner.invoke(
        app, ["train-ppo", "--task", "reach", "--out", str(out), "--resume", "--init-from", str(clone)]
    )
    assert resumed.exit_code == 2 and "--init-from has no effect with --resume" in resumed.output
    missing = tmp_path / "nothing.npz"
    fresh = tmp_path / "fresh"
    args = ["train-ppo", "--task", "reach", "--out", str(fresh), "--config", str(config), "--init-from", str(missing)]
    absent = runner.invoke(app, args)
    assert (
        absent.exit_code == 2 and absent.output.strip() == f"error: --init-from {str(missing)!r} is not a policy file"
    )
    assert not fresh.exists()  # refused before anything is made
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_text("not a policy file")
    refused = runner.invoke(app, [*args[:-1], str(corrupt)])
    assert refused.exit_code == 2 and "is corrupt or not a policy file" in refused.output, refused.output
    assert not fresh.exists()  # what only building the model can check: the run's folder is taken back
    # and so are the folders made above it; one that was there stays
    (tmp_path / "there").mkdir()
    for nested in (tmp_path / "new" / "run", tmp_path / "there" / "run"):
        refused = runner.invoke(app, [*args[:4], str(nested), *args[5:-1], str(corrupt)])
        assert refused.exit_code == 2 and "is corrupt or not a policy file" in refused.output, refused.output
    assert not (tmp_path / "new").exists() and list((tmp_path / "there").iterdir()) == []


@pytest.mark.rl
def test_init_from_on_the_command_line_starts_the_actor_from_the_file(trained_run, tmp_path, monkeypatch):
    """``--init-from FILE`` (PPO fine-tuning from a clone) overrides the config's ``init_from``: the run records it,
    and the model it trains starts with the file's actor."""
    import snac_gym.ppo.train as train_module

    out, config, _ = trained_run
    clone = out / "checkpoint" / "policy.npz"
    built = []
    build = train_module.build_model
    monkeypatch.setattr(train_module, "build_model", lambda cfg, venv: built.append(cfg) or build(cfg, venv))
    args = ["train-ppo", "--task", "reach", "--timesteps", "16", "--out", str(tmp_path / "ft"), "--config", str(config)]
    result = CliRunner().invoke(app, [*args, "--init-from", str(clone)])
    assert result.exit_code == 0, result.output
    assert built[0]["init_from"] == str(clone)
    assert json.loads((tmp_path / "ft" / "config.json").read_text())["init_from"] == str(clone)


@pytest.fixture
def terminal_sigint():
    """SIGINT raising KeyboardInterrupt, as in a terminal (a shell starts background jobs, and so
    possibly CI, with SIGINT ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.rl
def test_ctrl_c_leaves_a_usable_checkpoint_and_resume_continues(
    tmp_path, monkeypatch, reach_env, terminal_sigint, tiny_ppo
):
    import snac_gym.ppo.train as train_module

    original = train_module.make_training_env
    counter = {"steps": 0}

    class PressCtrlC(gym.Wrapper):
        """Sends SIGINT to this process at the 40th training step, as Ctrl-C in a terminal does."""

        def step(self, action):
            counter["steps"] += 1
            if counter["steps"] == 40:
                signal.raise_signal(signal.SIGINT)
            return self.env.step(action)

    monkeypatch.setattr(train_module, "make_training_env", lambda config: PressCtrlC(original(config)))
    out = tmp_path / "run"
    result = train_module.train_ppo(
        "reach", out, timesteps=96, seed=1, config_path=tiny_ppo(tmp_path), log=lambda s: None
    )
    assert result.status == "interrupted" and result.timesteps < 96
    assert json.loads((out / "state.json").read_text())["status"] == "interrupted"
    policy = PPOPolicy(reach_env, model_path=result.checkpoint_policy)
    assert np.all(np.isfinite(policy.act(_observations("reach", count=1)[0])))

    monkeypatch.setattr(train_module, "make_training_env", original)
    resumed = train_module.train_ppo("reach", out, timesteps=96, resume=True, log=lambda s: None)
    assert resumed.status == "finished" and resumed.timesteps >= 96
    state = json.loads((out / "state.json").read_text())
    assert [s["start_timesteps"] for s in state["segments"]] == [0, result.timesteps]
    assert (out / "logs" / f"segment_{result.timesteps}" / "progress.csv").is_file()
    assert train_module.train_ppo("reach", out, timesteps=96, resume=True, log=lambda s: None).status == "already-done"


@pytest.mark.rl
def test_timesteps_short_of_a_whole_rollout_are_rounded_up_and_the_run_says_so(tmp_path, tiny_ppo):
    """PPO collects whole rollouts (the tiny config's: 2 envs × 16 steps): 40 timesteps asked train 64. The start line
    says so, and the progress and evaluation lines count to 64 (they counted to 40: ``64/40 timesteps (160 %)``)."""
    import snac_gym.ppo.train as train_module

    logged: list[str] = []
    progress: list[str] = []
    config = tiny_ppo(tmp_path)
    result = train_module.train_ppo(
        "reach", tmp_path / "run", timesteps=40, config_path=config, log=logged.append, progress=progress.append
    )
    assert result.status == "finished" and result.timesteps == 64
    assert logged[0].startswith(
        "training PPO on reach for 64 timesteps: 40 asked, rounded up to whole rollouts of 16 steps of each of the "
        "2 dummy envs (seed"
    )
    assert progress and progress[-1].startswith("train-ppo: reach 64/64 timesteps (100 %)")
    assert all("/64 timesteps" in line for line in progress)
    assert any(line.startswith("[reach] 64/64 steps") for line in logged)
    # Resumed to a target past the end: counted from where it stands, to the next whole rollout.
    logged.clear()
    train_module.train_ppo("reach", tmp_path / "run", timesteps=100, resume=True, log=logged.append)
    assert "for 128 timesteps: 100 asked" in logged[0]


# -- load errors ------------------------------------------------------------------------------
@pytest.fixture
def shipped_reach_file():
    return PolicyFile.load(shipped_model_path("reach"))


def test_missing_file_fails_clearly(reach_env, tmp_path):
    missing = tmp_path / "nope.npz"
    with pytest.raises(MissingPolicyFileError, match="does not exist.*train-ppo") as info:
        make_policy("ppo", reach_env, model_path=missing)
    assert isinstance(info.value, FileNotFoundError) and isinstance(info.value, ValueError)
    assert str(missing) in str(info.value)


def test_corrupt_files_fail_clearly(reach_env, tmp_path):
    good = shipped_model_path("reach").read_bytes()
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good[: len(good) // 2])
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a policy file" * 10)
    no_metadata = tmp_path / "plain.npz"
    np.savez(no_metadata, weights=np.zeros(3))
    for path, message in ((truncated, "corrupt"), (garbage, "corrupt"), (no_metadata, "no metadata")):
        with pytest.raises(PolicyFileError, match=message):
            PPOPolicy(reach_env, model_path=path)


def test_altered_weights_fail_the_checksum(reach_env, tmp_path, shipped_reach_file):
    with zipfile.ZipFile(shipped_model_path("reach")) as source:
        entries = {name: source.read(name) for name in source.namelist()}
    bias = np.array(shipped_reach_file.action_layer[1])
    bias[0] += 1e-3
    import io

    buffer = io.BytesIO()
    np.save(buffer, bias)
    entries["action_bias.npy"] = buffer.getvalue()
    tampered = tmp_path / "tampered.npz"
    with zipfile.ZipFile(tampered, "w") as target:
        for name, data in entries.items():
            target.writestr(name, data)
    with pytest.raises(PolicyFileError, match="checksum"):
        PPOPolicy(reach_env, model_path=tampered)


def test_a_policy_of_another_task_robot_or_layout_is_refused(reach_env, tmp_path, shipped_reach_file):
    track_env = gym.make(ENV_OF_TASK["track"])
    with pytest.raises(PolicyFileError, match="trained for task 'reach' but the env's task is 'track'"):
        make_policy("ppo", track_env, model_path=shipped_model_path("reach"))
    track_env.close()

    base = PolicyContext.from_env(reach_env)
    ur5 = Kinematics("ur5")
    ur5_context = PolicyContext(ur5, base.dt, ur5.velocity_limits, base.layout, "reach")
    with pytest.raises(PolicyFileError, match="robot 'ur10'"):
        PPOPolicy(ur5_context, model_path=shipped_model_path("reach"))

    # a well-formed file for a 7-joint observation layout
    layout7 = ObservationLayout(7, 3)
    rng = np.random.default_rng(0)
    width = feature_size(layout7)
    seven = PolicyFile(
        hidden=((rng.normal(size=(4, width)).astype(np.float32), np.zeros(4, np.float32)),),
        action_layer=(rng.normal(size=(7, 4)).astype(np.float32), np.zeros(7, np.float32)),
        activation="tanh",
        obs_mean=np.zeros(width),
        obs_var=np.ones(width),
        obs_epsilon=1e-8,
        obs_clip=10.0,
        features=FeatureSpec(),
        metadata={**shipped_reach_file.metadata, "layout": {"n_joints": 7, "task_dim": 3, "size": layout7.size}},
    )
    path = seven.save(tmp_path / "seven.npz")
    with pytest.raises(PolicyFileError, match="observation layout"):
        PPOPolicy(reach_env, model_path=path)


def test_bad_action_scale_and_observation_are_refused(reach_env):
    for bad in (0, -1, float("nan"), "x"):
        with pytest.raises(ValueError, match="action_scale"):
            PPOPolicy(reach_env, action_scale=bad)
    with pytest.raises(ValueError, match="shape"):
        PPOPolicy(reach_env).act(np.zeros(5))


# -- the shipped policies --------------------------------------------------------------------------
@pytest.mark.parametrize("task", ["reach", "track"])
def test_shipped_policies_load_by_default_and_are_small(task):
    path = shipped_model_path(task)
    assert path.is_file() and path.stat().st_size < 1_000_000
    env = gym.make(ENV_OF_TASK[task])
    policy = make_policy("ppo", env)
    assert policy.model_path == path and policy.model.task == task
    assert policy.model.metadata["versions"]["snac_gym"] and policy.model.metadata["timesteps"] > 0
    env.close()


def test_policy_acts_on_the_observation_alone_deterministically(reach_env):
    policy = make_policy("ppo", reach_env)
    observations = _observations("reach", count=10)
    first = np.array([policy.act(obs) for obs in observations])
    policy.reset(seed=99)
    np.testing.assert_array_equal(np.array([policy.act(obs) for obs in observations]), first)
    # the joint-velocity field differs between the env and the kinematic engine (measured vs last command): not read
    changed = observations.copy()
    changed[:, policy.layout.slices["qdot"]] = np.random.default_rng(0).normal(size=(10, 6))
    np.testing.assert_array_equal(np.array([policy.act(obs) for obs in changed]), first)
    # a PolicyContext (the evaluator's and the real robot's way) builds the same policy
    from_context = PPOPolicy(PolicyContext.from_env(reach_env))
    np.testing.assert_array_equal(np.array([from_context.act(obs) for obs in observations]), first)
    assert np.all(np.abs(first) <= policy.velocity_limits)


def test_action_scale_scales_the_feedback_gain_not_the_network_input(reach_env):
    """The shipped (task-relative) policies: the knob multiplies the gain of the error feedback; the
    command equals the damped least-squares solution for that task velocity, computed independently."""
    assert PPOPolicy.effort_parameter == "action_scale"
    observations = _observations("track", count=10)
    track_env = gym.make(ENV_OF_TASK["track"])
    for scale in (0.5, 2.0):
        policy = PPOPolicy(track_env, action_scale=scale)
        model = policy.model
        assert model.features.task_relative
        features = observation_features(observations, policy.layout, model.features, action_scale=scale)
        np.testing.assert_array_equal(features, observation_features(observations, policy.layout, model.features))
        action = np.clip(model.network_action(model.normalise(features)), -1, 1)
        expected = _independent_task_relative_command(policy, observations, action, scale)
        np.testing.assert_allclose(policy.act_batch(observations), expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.array([policy.act(obs) for obs in observations]), expected, rtol=0, atol=1e-9)
    huge = PPOPolicy(track_env, action_scale=100.0).act_batch(observations)
    assert np.all(np.abs(huge) <= track_env.unwrapped.velocity_limits)
    track_env.close()


def test_a_joint_space_policy_file_still_runs(reach_env, tmp_path, shipped_reach_file):
    """Version 2 files (the network commands joints and sees ln(action_scale)) keep their meaning."""
    layout = ObservationLayout(6, 3)
    spec = FeatureSpec.from_dict({**FeatureSpec().to_dict(), "version": 2})
    assert spec.action == "joint" and not spec.task_relative
    width = feature_size(layout, spec)
    rng = np.random.default_rng(1)
    joint = PolicyFile(
        hidden=((rng.normal(size=(8, width)).astype(np.float32), rng.normal(size=8).astype(np.float32)),),
        action_layer=(rng.normal(size=(6, 8)).astype(np.float32), np.zeros(6, np.float32)),
        activation="tanh",
        obs_mean=rng.normal(size=width),
        obs_var=np.ones(width),
        obs_epsilon=1e-8,
        obs_clip=10.0,
        features=spec,
        metadata=dict(shipped_reach_file.metadata),
    )
    path = joint.save(tmp_path / "joint.npz")
    observations = _observations("reach", count=10)
    for scale in (0.5, 2.0):
        policy = PPOPolicy(reach_env, model_path=path, action_scale=scale)
        features = observation_features(observations, policy.layout, policy.model.features, action_scale=scale)
        assert np.all(features[:, -1] == np.float32(np.log(scale)))
        action = np.clip(policy.model.network_action(policy.model.normalise(features)), -1, 1)
        expected = scale * spec.action_fraction * action * policy.velocity_limits
        np.testing.assert_allclose(policy.act_batch(observations), expected, rtol=0, atol=1e-12)
    # a spec whose action and version disagree is refused, naming both
    with pytest.raises(ValueError, match="does not go with action 'joint'"):
        FeatureSpec.from_dict({**spec.to_dict(), "version": 3})


def _kinematic_peak_effort(task, action_scale, count=8, steps=150):
    """Median over ``count`` evaluator samples of each rollout's peak max_j |u_j|/ū_j (θ += uΔt)."""
    from snac_gym.evaluation.samples import generate_samples

    from snac_gym.rollout import reference_trajectories
    from snac_gym.sampling import SampleSpace

    kinematics = Kinematics("ur10")
    layout = ObservationLayout(6, 3)
    limits = kinematics.velocity_limits
    policy = PPOPolicy(PolicyContext(kinematics, 0.008, limits, layout, task), action_scale=action_scale)
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, task, range(count))
    x_d, xdot_d, centres = reference_trajectories([s.reference for s in samples], np.arange(steps) * 0.008)
    q = np.array([s.q0 for s in samples])
    peaks = np.zeros(count)
    for k in range(steps):
        x = kinematics.forward_batch(q)
        obs = np.array(
            [layout.pack(q[i], np.zeros(6), x[i], x_d[i, k], xdot_d[i, k], centres[i]) for i in range(count)]
        )
        u = policy.act_batch(obs)
        peaks = np.maximum(peaks, (np.abs(u) / limits).max(axis=1))
        q = q + u * 0.008
    return float(np.median(peaks))


@pytest.mark.parametrize("task", ["reach", "track"])
def test_effort_grows_with_action_scale(task):
    """The evaluator's equal-effort search needs an effort that grows with the knob."""
    efforts = [_kinematic_peak_effort(task, scale) for scale in (0.5, 1.0, 2.0)]
    assert efforts[0] < efforts[1] < efforts[2], efforts


def test_shipped_reach_policy_reaches_within_a_millimetre(reach_env):
    """Closed loop in the PyBullet env, the evaluator's 12 s horizon, five random episodes (the policy
    was trained on the kinematic model; under Q = 4·I the optimum itself takes a median 6.3 s to 1 mm)."""
    policy = make_policy("ppo", reach_env)
    final_errors = []
    for seed in range(5):
        obs, _ = reach_env.reset(seed=seed)
        policy.reset(seed=seed)
        for _ in range(1500):
            obs, _, _, _, info = reach_env.step(policy.act(obs))
        final_errors.append(info["error_norm"])
    assert sum(error <= 0.001 for error in final_errors) >= 4, final_errors


def test_inference_needs_neither_torch_nor_stable_baselines3():
    code = (
        "import sys, gymnasium as gym, snac_gym; from snac_gym.policies import make_policy;"
        "env = gym.make('snac_gym/UR10Reach-v0'); obs, _ = env.reset(seed=0);"
        "make_policy('ppo', env).act(obs);"
        "assert 'torch' not in sys.modules and 'stable_baselines3' not in sys.modules, 'imported torch'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


# -- config ---------------------------------------------------------------------------------------
def test_configs_are_versioned_and_checked(tmp_path):
    for task in ("reach", "track"):
        config = resolve_config(task, timesteps=10, seed=7, n_envs=1)
        assert config["task"] == task and config["timesteps"] == 10 and config["seed"] == 7
        assert config["config_version"] == 1 and config["vec_env"]["n_envs"] == 1
    with pytest.raises(ValueError, match="for task 'reach', not 'track'"):
        resolve_config("track", default_config_path("reach"))
    config = load_config(default_config_path("reach"))
    for change, message in (
        ({"config_version": 2}, "config_version"),
        ({"colour": 1}, "unknown key colour"),
        ({"ppo": {**config["ppo"], "lr": 1}}, "unknown key ppo.lr"),
    ):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps({**config, **change}))
        with pytest.raises(ValueError, match=message):
            load_config(path)
    # a policy file's feature spec of another version is refused
    with pytest.raises(ValueError, match="version 1"):
        FeatureSpec.from_dict({**FeatureSpec().to_dict(), "version": 1})


def test_paper_pose_episode_through_registry(reach_env):
    """``make_policy('ppo')`` from the paper's θ0 gives finite commands inside the limits."""
    policy = make_policy("ppo", reach_env)
    obs, _ = reach_env.reset(seed=0, options={"q0": list(PAPER_Q0)})
    for _ in range(20):
        u = policy.act(obs)
        assert u.shape == (6,) and np.all(np.isfinite(u))
        obs, *_ = reach_env.step(u)


# -- training curves -------------------------------------------------------------------------------
def _synthetic_run(folder, total=600_064, every=50_000):
    """A run folder as train_ppo leaves it (config, evaluations.csv, one SB3 progress.csv), made up."""
    config = load_config(default_config_path("reach"))
    config.update(timesteps=total, seed=0)
    (folder / "logs" / "segment_0").mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps(config))
    steps = list(range(every, total, every)) + [total]
    rows = [
        "timesteps,wall_time_s,success_rate,success_rate_4s,success_rate_8s,mean_cost,mean_final_error_m,"
        "median_final_error_m,mean_error_2nd_half_m,median_error_2nd_half_m,is_best"
    ]
    for i, step in enumerate(steps):
        rate = min(1.0, i / 4)
        rows.append(f"{step},{i * 50.0},{rate},{rate},{rate},{30 + 20 * i},0.01,0.01,0.01,0.01,{int(i == 3)}")
    (folder / "evaluations.csv").write_text("\n".join(rows) + "\n")
    progress = ["time/total_timesteps,rollout/ep_rew_mean"]
    progress += [f"{step},{-8000 + step / 75}" for step in range(2048, total, 2048)]
    (folder / "logs" / "segment_0" / "progress.csv").write_text("\n".join(progress) + "\n")


@pytest.mark.parametrize("total", [600_064, 2_400_000, 96])
def test_training_curve_tick_labels_do_not_overlap(tmp_path, total):
    """The x tick labels (timesteps) of every panel stand apart once drawn (at 600k they touched: 100000200000...)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from snac_gym.ppo.train import plot_training_curves, training_curves_figure

    _synthetic_run(tmp_path, total=total, every=max(1, total // 12))
    fig = training_curves_figure(tmp_path)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        for axis in fig.axes:
            labels = [label for label in axis.get_xticklabels() if label.get_visible() and label.get_text()]
            assert len(labels) >= 2
            boxes = sorted((label.get_window_extent(renderer) for label in labels), key=lambda box: box.x0)
            for left, right in zip(boxes, boxes[1:]):  # apart by half a line at least, not just not touching
                assert right.x0 - left.x1 >= 0.5 * left.height, [label.get_text() for label in labels]
    finally:
        plt.close(fig)
    assert plot_training_curves(tmp_path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("task", ["reach", "track"])
def test_shipped_policies_beat_dls_on_the_cost_they_were_trained_on(task):
    """The shipped files' claim, on 16 evaluator samples (θ += uΔt, the evaluator's horizon): under
    Σ(4‖e‖² + ‖u‖²)Δt the median PPO/DLS cost ratio is below 1 (0.88 / 0.90 on 1000 samples) and
    every rollout ends within the task's tolerance."""
    from snac_gym.baselines.dls import DLSPolicy
    from snac_gym.evaluation.samples import generate_samples

    from snac_gym.rollout import reference_trajectories
    from snac_gym.sampling import SampleSpace

    kinematics = Kinematics("ur10")
    layout, limits, dt, count = ObservationLayout(6, 3), kinematics.velocity_limits, 0.008, 16
    steps = 1500 if task == "reach" else 2500
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, task, range(count))
    x_d, xdot_d, centres = reference_trajectories([s.reference for s in samples], np.arange(steps + 1) * dt)
    costs, final_errors = {}, {}
    for name, make in (("ppo", PPOPolicy), ("dls", DLSPolicy)):
        policy = make(PolicyContext(kinematics, dt, limits, layout, task))
        policy.reset_batch(list(range(count))) if hasattr(policy, "reset_batch") else policy.reset(0)
        q = np.array([s.q0 for s in samples])
        cost, errors = np.zeros(count), []
        for k in range(steps):
            x = kinematics.forward_batch(q)
            obs = np.zeros((count, layout.size))  # layout.pack of each row, as arrays
            for field, value in (
                ("q", q),
                ("x", x),
                ("x_d", x_d[:, k]),
                ("xdot_d", xdot_d[:, k]),
                ("e", x - x_d[:, k]),
                ("x_c", centres),
            ):
                obs[:, layout.slices[field]] = value
            u = policy.act_batch(obs)
            e = x - x_d[:, k]
            cost += (4.0 * np.einsum("ij,ij->i", e, e) + np.einsum("ij,ij->i", u, u)) * dt
            errors.append(np.linalg.norm(e, axis=1))
            q = q + u * dt
        costs[name] = cost
        errors = np.array(errors)
        final_errors[name] = errors[-1] if task == "reach" else errors[steps // 2 :].mean(axis=0)
    assert np.median(costs["ppo"] / costs["dls"]) < 1.0, costs
    assert np.all(final_errors["ppo"] <= (0.001 if task == "reach" else 0.005)), final_errors["ppo"]


def test_a_config_trains_on_the_workspace_when_its_env_says_so(tmp_path):
    """``env.sample_space: "workspace"`` reaches every env the trainer builds: the batched training envs, the
    single ones and the periodic evaluation's; another region name is refused by name."""
    from snac_gym.ppo.config import ConfigError, env_arguments, validate_config

    config = resolve_config("reach", n_envs=2)
    config["env"]["sample_space"] = "workspace"
    validate_config({k: v for k, v in config.items() if k not in ("config_file", "versions")})
    assert env_arguments(config)["sample_space"].region == "workspace"
    pytest.importorskip("stable_baselines3")
    from snac_gym.ppo.train import make_training_env
    from snac_gym.ppo.vec_env import PPOVecEnv

    assert PPOVecEnv(config).vector_env.single_env.sample_space.region == "workspace"
    assert make_training_env(config).unwrapped.sample_space.region == "workspace"
    assert env_arguments(resolve_config("reach")).get("sample_space") is None  # the default: the cuboid
    config["env"]["sample_space"] = "everywhere"
    with pytest.raises(ConfigError, match="env.sample_space must be one of cuboid, workspace, got 'everywhere'"):
        validate_config({k: v for k, v in config.items() if k not in ("config_file", "versions")})
