"""The last inputs taken silently (or answered with a raw exception), each refused where it enters with a
message naming the argument or the option the user typed."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from snac_gym.evaluation import EvaluationConfig

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.common.validation import boolean
from snac_gym.control.cost import trajectory_cost
from snac_gym.sampling import SampleSpace

ID = "snac_gym/UR10Reach-v0"


@pytest.mark.parametrize("value", ["no", 1, 0.0, None])
def test_a_switch_that_is_not_a_bool_is_refused(value):
    with pytest.raises(ValueError, match=rf"terminate_on_success must be True or False, got {value!r}"):
        gym.make(ID, physics="kinematic", terminate_on_success=value)
    with pytest.raises(ValueError, match=r"terminate_on_success must be True or False"):
        gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", terminate_on_success=value)
    with pytest.raises(ValueError, match=r"progress must be True or False"):
        EvaluationConfig(out=Path("unused"), progress=value).validate()
    assert boolean("x", np.bool_(True)) is True
    env = gym.make(ID, physics="kinematic", terminate_on_success=np.bool_(True)).unwrapped
    assert env.terminate_on_success is True
    env.close()


@pytest.mark.parametrize("value", [1e9, 0.0, -1.0, float("nan"), "0.01", True])
def test_a_success_tolerance_beyond_a_metre_is_refused(value):
    with pytest.raises(ValueError, match=r"success_tolerance \(m\) must be a (finite|real) number in \(0, 1\]"):
        gym.make(ID, physics="kinematic", success_tolerance=value)


def test_a_trajectory_cost_that_overflows_is_refused():
    with pytest.raises(ValueError, match=r"the error term of the trajectory cost overflows float64"):
        trajectory_cost(np.full((2, 3), 1e200), np.zeros((2, 6)), 0.008)
    with pytest.raises(ValueError, match=r"the effort term of the trajectory cost overflows float64"):
        trajectory_cost(np.zeros((2, 3)), np.full((2, 6), 1e160), 0.008)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"min_singular_value": -1}, r"min_singular_value \(m/rad\) must be a finite number in \[0, inf\], got -1"),
        ({"low": (np.nan, 0.0, 0.0)}, r"low must be finite, got NaN or inf"),
        ({"high": (1.0, 1.0)}, r"high must have shape \(3,\), got \(2,\)"),
        ({"low": (0, 0, 0), "high": (1, -1, 1)}, r"sample cuboid needs low < high"),
        ({"ellipse_points": 0}, r"ellipse_points must be a whole number in \[4, 100000\], got 0"),
        ({"ellipse_points": 8.5}, r"ellipse_points must be a whole number"),
        ({"semi_axis_range": (0.2, 0.05)}, r"semi_axis_range \(m\) must be \(low, high\) with 0.001 <= low <= high"),
        ({"speed_range": (0.0, 0.3)}, r"speed_range \(rad/s\) must be \(low, high\) with 0.001 <= low <= high"),
        ({"speed_range": (0.05, 1e3)}, r"speed_range and semi_axis_range allow an ellipse point speed"),
        ({"joint_margin": -0.1}, r"joint_margin \(rad\) must be a finite number"),
        ({"joint_margin": 10.0}, r"joint_margin \(rad\) must be a finite number in \[0, 3.14159\]"),
        ({"region": "cube"}, r"region must be one of \('cuboid', 'workspace'\), got 'cube'"),
    ],
)
def test_a_sample_space_is_checked_when_built(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SampleSpace(**kwargs)


def test_a_sample_space_by_an_unknown_name_is_refused():
    with pytest.raises(
        ValueError,
        match=r"sample_space must be a snac_gym.sampling.SampleSpace, None or one of "
        r"'cuboid', 'workspace', got 'cube'",
    ):
        gym.make(ID, physics="kinematic", sample_space="cube")
    env = gym.make(ID, physics="kinematic", sample_space="workspace").unwrapped
    assert env.sample_space.region == "workspace"
    env.close()


@pytest.mark.parametrize("physics", ["kinematic", "pybullet", "mujoco"])
def test_step_and_reset_after_close_say_so(physics):
    if physics == "mujoco":
        pytest.importorskip("mujoco")
    env = gym.make(ID, physics=physics).unwrapped
    env.reset(seed=0)
    env.close()
    with pytest.raises(RuntimeError, match=rf"step\(\) after close\(\): the {physics} arm is closed; make a new env"):
        env.step(np.zeros(6))
    with pytest.raises(RuntimeError, match=r"reset\(\) after close\(\): .* make a new env"):
        env.reset(seed=0)


def test_a_closed_vector_env_says_so():
    vector = gym.make_vec(ID, 2, vectorization_mode="vector_entry_point")
    vector.reset(seed=0)
    vector.close()
    with pytest.raises(RuntimeError, match=r"step\(\) after close\(\)"):
        vector.step(np.zeros((2, 6)))
    with pytest.raises(RuntimeError, match=r"reset\(\) after close\(\)"):
        vector.reset(seed=0)


def test_an_initial_command_of_the_wrong_length_is_refused():
    with pytest.raises(
        ValueError,
        match=r"initial_command must be u₋₁ of length 6 \(the commands' m\), shape \(6,\), "
        r"got shape \(5,\)",
    ):
        trajectory_cost(np.zeros((2, 3)), np.zeros((2, 6)), 0.008, initial_command=np.zeros(5))
    with pytest.raises(ValueError, match=r"initial_command must be finite"):
        trajectory_cost(np.zeros((2, 3)), np.zeros((2, 6)), 0.008, initial_command=np.full(6, np.nan))
    batch = trajectory_cost(np.zeros((4, 2, 3)), np.ones((4, 2, 6)), 0.01, initial_command=np.ones((4, 6)))
    assert np.all(batch.smoothness == 0.0)


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            ["real", "--connection", "sim", "--dry-run", "--recovery-timeout", "inf"],
            "error: --recovery-timeout must be a finite number in (0, 3600], got inf",
        ),
        (
            ["real", "--connection", "sim", "--dry-run", "--reconnect-timeout", "-1"],
            "error: --reconnect-timeout must be a finite number in (0, 600], got -1.0",
        ),
        (
            ["evaluate", "--samples", "2", "--effort-tolerance", "5"],
            "error: --effort-tolerance must be in (0, 1), got 5.0",
        ),
        (
            ["evaluate", "--samples", "2", "--q-scale", "-1"],
            "error: --q-scale must be a positive finite number, got -1.0",
        ),
        (
            ["evaluate", "--samples", "2", "--success-threshold", "2"],
            "error: --success-threshold must be in [0, 1], got 2.0",
        ),
        (
            ["evaluate", "--samples", "2", "--effort-target", "-1"],
            "error: --effort-target must be a positive finite number",
        ),
        (["evaluate", "--samples", "2", "--workers", "100000"], "error: --workers must be between 1 and"),
        (["evaluate", "--samples", "100000000000"], "error: --samples must be between 1 and"),
        (
            ["evaluate", "--samples", "2", "--effort-samples", "100000000000"],
            "error: --effort-samples must be between 0 and",
        ),
        (["evaluate", "--samples", "2", "--cost", "foo"], "error: --cost must be one of ('table1', 'hjb'), got 'foo'"),
        (["evaluate", "--samples", "2", "--udot-start", "foo"], "error: --udot-start must be one of ('rest', 'first')"),
        (["evaluate", "--samples", "2", "--engine", "foo"], "error: --engine must be one of"),
        (
            ["evaluate", "--samples", "2", "--seed", "99999999999"],
            "error: --seed must be a whole number in [0, 4294967295]",
        ),
        (["evaluate", "--samples", "2", "--reference-limits", "foo"], "error: --reference-limits must be one of"),
        (["evaluate", "--samples", "2", "--horizon", "1e9"], "error: --horizon: the reach horizon must be between"),
        (["evaluate", "--samples", "2", "--robot", "foo"], "error: --robot: unknown robot 'foo'"),
        (["evaluate", "--samples", "2", "--controllers", "foo"], "error: --controllers: unknown controller 'foo'"),
        (
            ["train-ppo", "--task", "reach", "--seed", "-1"],
            "error: --seed must be an integer in [0, 4294967295], got -1",
        ),
        (
            ["train-ppo", "--task", "reach", "--vec-env", "foo"],
            "error: --vec-env must be 'dummy' or 'subproc' or 'batched'",
        ),
        (
            ["emulate-ur", "--port-base", "-1", "--duration", "0.2"],
            "error: --port-base must be 0 (free ports) or in [1024, 65530]",
        ),
        (
            ["emulate-ur", "--port-base", "0", "--duration", "0.2", "--speed-scaling", "5"],
            "error: --speed-scaling must be in (0, 1]",
        ),
        (["emulate-ur", "--host", "", "--duration", "0.2"], "error: --host must be a loopback address (127.x.x.x)"),
    ],
    ids=[
        "recovery-timeout",
        "reconnect-timeout",
        "effort-tolerance",
        "q-scale",
        "success-threshold",
        "effort-target",
        "workers",
        "samples",
        "effort-samples",
        "cost",
        "udot-start",
        "engine",
        "seed",
        "reference-limits",
        "horizon",
        "robot",
        "controllers",
        "ppo-seed",
        "ppo-vec-env",
        "port-base",
        "speed-scaling",
        "emulator-host",
    ],
)
def test_cli_refusals_name_the_option_typed(tmp_path, arguments, message):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    out = [] if arguments[0] == "emulate-ur" else ["--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, [*arguments, *out], terminal_width=200)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and lines[0].startswith(message), result.output


@pytest.mark.parametrize(
    ("module", "arguments", "message"),
    [
        (
            "mujoco",
            ["--engine", "mujoco"],
            "error: physics='mujoco' needs the 'mujoco' extra: pip install -e \".[mujoco]\"",
        ),
        ("ray", ["--ray", "local"], "error: --ray needs the 'ray' extra: pip install -e \".[ray]\""),
    ],
    ids=["engine", "ray"],
)
def test_an_extra_the_workers_need_is_asked_for_before_any_work(tmp_path, monkeypatch, module, arguments, message):
    """MuJoCo is imported by the evaluator's workers alone, Ray once the kernels are readied: without the check up
    front a MuJoCo run drew its samples and matched effort on the kinematic model (2000 rollouts of a 3-sample run)
    before a worker said the extra was missing, and a Ray run first said that the kernels compile."""
    import importlib.util

    import snac_gym.evaluation.runner as runner
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == module else found(name, *a))
    monkeypatch.setattr(runner, "open_executor", lambda *a, **k: pytest.fail("a worker pool was started"))
    monkeypatch.setattr(runner, "announce_compiles", lambda *a, **k: pytest.fail("the kernels were announced"))
    result = CliRunner().invoke(
        app,
        ["evaluate", "--samples", "3", "--controllers", "dls", *arguments, "--out", str(tmp_path)],
        terminal_width=200,
    )
    assert result.exit_code == 2, result.output
    assert result.output == message + "\n"
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--ray", "ray://"], "error: --ray 'ray://': use 'local', 'auto', HOST:PORT or ray://HOST:PORT"),
        (["--ray", "auto", "--workers", "2"], "error: --workers 2 has no effect on a Ray cluster (auto)"),
    ],
    ids=["address", "workers"],
)
def test_a_wrong_ray_option_is_named_before_the_missing_extra(tmp_path, monkeypatch, arguments, message):
    """Without Ray installed, what is wrong with the option itself is said first: installing the extra would not
    have made the command run."""
    import importlib.util

    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else found(name, *a))
    arguments = ["evaluate", "--samples", "3", "--controllers", "dls", *arguments, "--out", str(tmp_path)]
    result = CliRunner().invoke(app, arguments, terminal_width=200)
    assert result.exit_code == 2, result.output
    assert result.output.startswith(message), result.output
    assert not any(tmp_path.iterdir())


def test_export_samples_under_a_file_names_the_folder(tmp_path):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    blocker = tmp_path / "file"
    blocker.write_text("")
    target = blocker / "sub" / "samples.csv"
    result = CliRunner().invoke(
        app,
        [
            "evaluate",
            "--out",
            str(tmp_path / "out"),
            "--samples",
            "2",
            "--export-samples",
            str(target),
            "--export-only",
        ],
        terminal_width=300,
    )
    assert result.exit_code == 2, result.output
    assert (
        f"error: --export-samples {target}: its folder {target.parent} cannot be made, {blocker} is not a folder"
        in result.output
    )
