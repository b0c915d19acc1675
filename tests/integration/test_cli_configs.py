"""``train-ppo``, ``demo`` and ``bench``: every bad input is one line on stderr naming the field or
option and its range, exit code 2, no traceback, and nothing is built or created first."""

from __future__ import annotations

import copy
import io
import json
import pickle
import zipfile

import pytest
from typer.testing import CliRunner

from snac_gym.apps.bench import MAX_ACT_CALLS, MAX_BENCH_STEPS
from snac_gym.apps.cli import app
from snac_gym.ppo.config import (
    MAX_SEED,
    ConfigError,
    TrainingConfig,
    default_config_path,
    env_keywords,
    load_config,
    validate_config,
)


def _one_line_error(result, *fragments: str) -> str:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and isinstance(result.exception, SystemExit), result.exception
    assert result.stdout == "", result.stdout  # nothing built, nothing printed: the error alone, on stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def _config_with(tmp_path, dotted: str, value, task: str = "reach"):
    """The shipped config of ``task`` with ``dotted`` set to ``value`` (a new key if it is not there)."""
    config = copy.deepcopy(load_config(default_config_path(task)))
    *sections, key = dotted.split(".")
    target = config
    for section in sections:
        target = target[section]
    target[key] = value
    path = tmp_path / "config.json"
    path.write_text(json.dumps(config))
    return path


def _train(*arguments: str):
    return CliRunner().invoke(app, ["train-ppo", "--no-progress", "--task", "reach", *arguments])


@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_shipped_configs_validate_unchanged(task):
    path = default_config_path(task)
    raw = json.loads(path.read_text())
    config = validate_config(raw, str(path))
    assert isinstance(config, TrainingConfig) and config.task == task
    assert config.ppo.batch_size == 4096 and config.ppo.net_arch == {"pi": (64, 64), "vf": (128, 128)}
    assert config.evaluation.every_timesteps == 200_000 and config.vec_env.kind == "batched"
    assert config.features.action == "task-relative" and config.features.version == 3
    assert config.reward.type == "cost" and config.reward.q_scale == 4.0
    assert load_config(path) == raw  # the dict a run writes into OUT/config.json is the file's, untouched


@pytest.mark.parametrize(
    ("dotted", "value", "message"),
    [
        ("ppo.batch_size", 0, "ppo.batch_size must be an integer ≥ 2, got 0"),
        ("ppo.n_epochs", 0, "ppo.n_epochs must be an integer ≥ 1, got 0"),
        ("evaluation.every_timesteps", 0, "evaluation.every_timesteps must be an integer ≥ 1, got 0"),
        ("vec_env.n_envs", "8", "vec_env.n_envs must be an integer in [1, 1024], got '8'"),
        ("timesteps", "1000", "timesteps must be an integer ≥ 1, got '1000'"),
        ("timesteps", 2e7, "timesteps must be an integer ≥ 1, got 20000000.0"),
        ("ppo.net_arch", {"pi": [64, -1], "vf": [64]}, "ppo.net_arch.pi[1] must be an integer in [1, 4096], got -1"),
        ("ppo.net_arch", {"pi": [64], "vf": [32.5]}, "ppo.net_arch.vf[0] must be an integer in [1, 4096], got 32.5"),
        ("ppo.gamma", 2, "ppo.gamma must be a number in [0, 1], got 2"),
        ("ppo.clip_range", -0.2, "ppo.clip_range must be a number > 0, got -0.2"),
        ("evaluation.horizons_s", [12.0, -4.0], "evaluation.horizons_s[1] must be a number in (0, 1000], got -4.0"),
        ("evaluation.success_error_m", -0.001, "evaluation.success_error_m must be a number > 0, got -0.001"),
        ("normalize.clip_obs", -10.0, "normalize.clip_obs must be a number > 0, got -10.0"),
        ("ppo.activation", "gelu", "ppo.activation must be 'tanh' or 'relu', got 'gelu'"),
        ("ppo.lr", 0.001, "unknown key ppo.lr: the ppo section takes learning_rate, net_arch,"),
        ("colour", "blue", "unknown key colour: a config takes config_version, task,"),
        ("env.max_step", 100, "unknown env keyword env.max_step: the reach env takes dt, n_substeps, max_steps,"),
        ("env.max_steps", 0, "env.max_steps must be an integer ≥ 1, got 0"),
        ("seed", -1, "seed must be an integer in [0, 4294967295], got -1"),
    ],
)
def test_a_bad_config_field_is_one_line_naming_it_before_anything_is_made(tmp_path, dotted, value, message):
    path = _config_with(tmp_path, dotted, value)
    out = tmp_path / "run"
    _one_line_error(_train("--out", str(out), "--config", str(path)), f"{path}: {message}")
    assert not out.exists()  # refused before the output folder, the envs or the model
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("(", r"\(")):
        load_config(path)  # the library path says the same


def test_env_keywords_are_the_env_constructors():
    accepted = env_keywords("reach")
    assert {"max_steps", "terminate_on_success", "dt"} <= set(accepted) and "robot" not in accepted


def test_command_line_overrides_are_checked_too(tmp_path):
    out = tmp_path / "run"
    _one_line_error(_train("--out", str(out), "--seed", "-1"), f"--seed must be an integer in [0, {MAX_SEED}], got -1")
    _one_line_error(
        _train("--out", str(out), "--vec-env", "threads"),
        "--vec-env must be 'dummy' or 'subproc' or 'batched', got 'threads'",
    )
    assert not out.exists()


@pytest.mark.parametrize("source", ["/dev/zero", "folder", "missing.json", "not-json"])
def test_a_config_file_that_cannot_be_read_is_one_line(tmp_path, source):
    path = {"folder": tmp_path, "missing.json": tmp_path / "missing.json", "not-json": tmp_path / "c.json"}.get(
        source, source
    )
    (tmp_path / "c.json").write_text('{"config_version": 1,')
    _one_line_error(_train("--out", str(tmp_path / "run"), "--config", str(path)), f"cannot read PPO config {path}")


@pytest.mark.parametrize("kind", ["file", "/dev/null"])
def test_train_out_that_is_a_file_is_one_line(tmp_path, kind):
    out = tmp_path / "taken.txt" if kind == "file" else "/dev/null"
    if kind == "file":
        out.write_text("keep me")
    what = "a file" if kind == "file" else "a device"
    _one_line_error(_train("--out", str(out)), f"the output folder {out} is {what}, not a folder; choose another --out")
    if kind == "file":
        assert out.read_text() == "keep me"


def _checkpoint_folder(tmp_path, model: bytes, statistics: bytes):
    out = tmp_path / "run"
    (out / "checkpoint").mkdir(parents=True)
    (out / "config.json").write_text(default_config_path("reach").read_text())
    (out / "checkpoint" / "model.zip").write_bytes(model)
    (out / "checkpoint" / "vecnormalize.pkl").write_bytes(statistics)
    return out


def _zip_bytes() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("data", "{}" * 1000)
    return buffer.getvalue()


@pytest.mark.rl  # the checkpoint is read by stable-baselines3
@pytest.mark.parametrize("damaged", ["model.zip", "vecnormalize.pkl"])
def test_resume_from_a_truncated_checkpoint_is_one_line_naming_the_file(tmp_path, damaged):
    model, statistics = _zip_bytes(), pickle.dumps({"clip_obs": 10.0})
    if damaged == "model.zip":
        model = model[: len(model) // 2]
    else:
        statistics = statistics[:-5]
    out = _checkpoint_folder(tmp_path, model, statistics)
    line = _one_line_error(_train("--out", str(out), "--resume"), "is corrupt or truncated")
    assert f"--resume: the checkpoint {out / 'checkpoint' / damaged} is corrupt" in line
    assert json.loads((out / "config.json").read_text()) == json.loads(default_config_path("reach").read_text())


def _demo(tmp_path, *arguments: str):
    return CliRunner().invoke(app, ["demo", "--steps", "5", "--no-plots", *arguments])


def test_demo_seed_must_be_a_numpy_seed(tmp_path):
    _one_line_error(
        _demo(tmp_path, "--seed", "-1", "--out", str(tmp_path / "d")),
        "--seed must be an integer ≥ 0 (a NumPy seed), got -1",
    )
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("kind", ["file", "/dev/null"])
def test_demo_out_must_be_a_usable_folder(tmp_path, kind):
    out = tmp_path / "taken.txt" if kind == "file" else "/dev/null"
    if kind == "file":
        out.write_text("keep me")
    what = "a file" if kind == "file" else "a device"
    _one_line_error(_demo(tmp_path, "--out", str(out)), f"the output folder {out} is {what}, not a folder")


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--steps", str(10**12)], f"--steps must be between 100 and {MAX_BENCH_STEPS:,}, got {10**12}"),
        (["--steps", "99"], f"--steps must be between 100 and {MAX_BENCH_STEPS:,}, got 99"),
        (
            ["--act", "--act-calls", str(MAX_ACT_CALLS + 1)],
            f"--act-calls must be between 100 and {MAX_ACT_CALLS:,}, got {MAX_ACT_CALLS + 1}",
        ),
        (["--act-calls", "-5"], f"--act-calls must be between 100 and {MAX_ACT_CALLS:,}, got -5"),
    ],
)
def test_bench_counts_are_bounded_before_anything_runs(arguments, message):
    _one_line_error(CliRunner().invoke(app, ["bench", "--no-panda", *arguments]), message)


def test_bench_bounds_are_what_the_help_states():
    assert MAX_BENCH_STEPS == MAX_ACT_CALLS == 1_000_000
    assert MAX_ACT_CALLS * 8 <= 8_000_000  # the timings array at the bound (int64)
    text = CliRunner().invoke(app, ["bench", "--help"], terminal_width=400).output
    assert "100 to 1,000,000" in text and "8 B each" in text


def test_a_feature_version_that_does_not_go_with_the_action_kind_is_refused():
    config = load_config(default_config_path("reach"))
    config["features"] = {**config["features"], "version": 2}  # a joint-space version with task-relative actions
    with pytest.raises(ConfigError, match="version 2 does not go with action 'task-relative'"):
        validate_config(config, "reach.json")
    config["features"].pop("action")  # without a kind, the version's own (joint) is meant: valid
    validate_config(config, "reach.json")
