"""Property-based tests (Hypothesis) of the command line: any value of an option gives the command's
result or a refusal (exit 2) in a line that names the option, never a traceback, another exit code or a
hang. The commands run through click's test runner, each example bounded in time; options whose valid
values start long work are drawn from their invalid values only (the valid ones are the other tests').
"""

from __future__ import annotations

import string
from datetime import timedelta

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_properties_api import bounded
from typer.testing import CliRunner

from snac_gym.apps.cli import app

SETTINGS = settings(
    max_examples=25,
    derandomize=True,
    database=None,
    deadline=timedelta(seconds=30),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

numbers = st.one_of(
    st.integers(-(10**13), 10**13).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e308", "1e-320", "0", "-0", "True", "0x10", "1_000", " 3", "3 "]),
)
lists = st.lists(st.one_of(numbers, st.just("")), min_size=0, max_size=8).map(",".join)
texts = st.text(alphabet=string.printable, max_size=14)
values = st.one_of(numbers, lists, texts)


def _check(outcome, option: str) -> None:
    """Exit 0, or exit 2 with a message naming ``option``; never an exception of the command's own."""
    assert outcome.exception is None or isinstance(outcome.exception, SystemExit), repr(outcome.exception)
    assert outcome.exit_code in (0, 2), (outcome.exit_code, outcome.output)
    if outcome.exit_code == 2:
        text = " ".join(outcome.output.split())
        stem = option.lstrip("-").replace("-", "_")
        named = option in text or stem in text or option.lstrip("-").replace("-", " ") in text
        assert "error" in text.lower() or "invalid value" in text.lower(), text
        assert named, f"the refusal does not name {option}: {text}"


def _invoke(arguments: list[str]):
    with bounded(30):
        return CliRunner().invoke(app, arguments, terminal_width=200)


EVALUATE_OPTIONS = [
    "--samples",
    "--seed",
    "--cuboid",
    "--q-scale",
    "--model-error",
    "--task",
    "--controllers",
    "--effort-tolerance",
    "--success-threshold",
    "--sample-space",
    "--robot",
    "--udot-start",
    "--cost",
]


@SETTINGS
@given(option=st.sampled_from(EVALUATE_OPTIONS), value=values)
def test_evaluate_options(tmp_path_factory, option, value):
    out = tmp_path_factory.mktemp("evaluate")
    if option == "--samples" and value.strip().isdigit() and int(value) > 10_000:
        value = "-" + value  # a valid count this large is minutes of drawing: the refusal side only
    arguments = [
        "evaluate",
        "--out",
        str(out / "run"),
        "--export-only",
        "--export-samples",
        str(out / "s.csv"),
        "--no-progress",
        *(["--samples", "3"] if option != "--samples" else []),
        f"{option}={value}",
    ]
    _check(_invoke(arguments), option)


DEMO_OPTIONS = ["--seed", "--duration", "--task", "--controller", "--robot", "--model-error"]


@SETTINGS
@given(option=st.sampled_from(DEMO_OPTIONS), value=values)
def test_demo_options(tmp_path_factory, option, value):
    out = tmp_path_factory.mktemp("demo")
    if option == "--duration":
        try:
            if float(value) > 0.5:
                value = "-" + value  # long demos: the refusal side only
        except ValueError:
            pass
    steps = [] if option == "--duration" else ["--steps", "10"]
    _check(_invoke(["demo", "--out", str(out), "--no-plots", *steps, f"{option}={value}"]), option)


REAL_OPTIONS = [
    "--speed-scale",
    "--max-acceleration",
    "--max-tcp-mismatch",
    "--joint-margin",
    "--q0",
    "--target",
    "--task-box",
    "--series",
    "--robot",
    "--seed",
    "--steps",
    "--ellipse-radius",
]


@SETTINGS
@given(option=st.sampled_from(REAL_OPTIONS), value=values)
def test_real_options_on_a_dry_run(tmp_path_factory, option, value):
    out = tmp_path_factory.mktemp("real")
    if option == "--steps" and value.strip().isdigit() and int(value) > 50:
        value = "-" + value  # real time: the refusal side only
    steps = [] if option == "--steps" else ["--steps", "5"]
    arguments = [
        "real",
        "--connection",
        "sim",
        "--dry-run",
        "--no-plots",
        "--out",
        str(out),
        *steps,
        f"{option}={value}",
    ]
    outcome = _invoke(arguments)
    if outcome.exit_code == 4:  # a valid but unsafe setting: the safety layer stopped the (simulated) arm
        assert "safety" in outcome.output.lower(), outcome.output
        return
    _check(outcome, option)


EMULATOR_OPTIONS = [
    "--speed-scaling",
    "--tcp-offset",
    "--latency-spike",
    "--protective-stop-at",
    "--drop-at",
    "--series",
    "--robot",
    "--stale-at",
    "--watchdog-expiry-at",
]


@SETTINGS
@given(option=st.sampled_from(EMULATOR_OPTIONS), value=values)
def test_emulator_options(option, value):
    _check(_invoke(["emulate-ur", "--port-base", "0", "--duration", "0", f"{option}={value}"]), option)


@SETTINGS
@given(
    option=st.sampled_from(["--steps", "--act-calls"]),
    value=st.one_of(st.integers(-(10**13), 99).map(str), st.integers(1_000_001, 10**13).map(str), texts),
)
def test_bench_counts_outside_their_range(option, value):
    _check(_invoke(["bench", "--no-panda", f"{option}={value}"]), option)


@SETTINGS
@given(option=st.sampled_from(["--n-envs", "--timesteps", "--seed", "--vec-env", "--task"]), value=values)
def test_train_ppo_options(tmp_path_factory, option, value):
    pytest.importorskip("stable_baselines3")
    out = tmp_path_factory.mktemp("ppo")
    task = [] if option == "--task" else ["--task", "reach"]
    # --resume on an empty folder: a value the options accept ends at "no checkpoint", never in a training run
    outcome = _invoke(["train-ppo", *task, "--out", str(out / "run"), "--resume", "--no-progress", f"{option}={value}"])
    if outcome.exit_code == 2 and "holds no checkpoint to continue" in outcome.output:
        return
    _check(outcome, option)
