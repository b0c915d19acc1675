"""Which controllers a run compares: the default set (whose knobs ship), ``all``, and names given one by one."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
from snac_gym.evaluation import EvaluationConfig
from snac_gym.evaluation.controllers import ALL_CONTROLLERS, DEFAULT_CONTROLLERS, resolve_controllers
from snac_gym.evaluation.effort.shipped import shipped_file

from snac_gym.policies import available_policies

README = Path(__file__).resolve().parents[2] / "README.md"


def _names(config: EvaluationConfig) -> list[str]:
    specs, _ = resolve_controllers(config)
    return [spec.name for spec in specs]


def test_without_names_a_run_compares_the_default_set_in_table_is_order(tmp_path):
    assert _names(EvaluationConfig(out=tmp_path)) == ["rnn", "svf", "snac", "dls", "lqr", "ppo", "snac-hjb"]
    assert set(DEFAULT_CONTROLLERS) < set(available_policies())  # the others are there, and not run by default


def test_the_default_set_is_the_one_whose_knobs_ship_and_the_readmes_main_command(tmp_path):
    """A first run without --controllers reads the shipped knobs (it would otherwise match every controller's
    effort on 1000 samples, for minutes): the file covers exactly the default set, on both tasks."""
    import json

    entries = json.loads(shipped_file().read_text())["entries"]
    for task in ("reach", "track"):
        shipped = {entry["record"]["controller"] for entry in entries if entry["record"]["task"] == task}
        assert shipped == set(DEFAULT_CONTROLLERS), task
    command = re.search(r"snac-gym evaluate [^\n]*--controllers (\S+)", README.read_text())
    assert command is not None
    assert set(command.group(1).split(",")) - {"optimal"} == set(DEFAULT_CONTROLLERS)


def test_all_is_every_registered_controller_and_one_that_cannot_be_built_is_left_out_with_its_reason(tmp_path):
    names = _names(EvaluationConfig(out=tmp_path, controllers=(ALL_CONTROLLERS, "optimal")))
    assert names[:3] == ["rnn", "svf", "snac"] and set(DEFAULT_CONTROLLERS) | {"mpc"} <= set(names)
    assert "optimal" not in names  # the reference row, solved apart
    assert EvaluationConfig(out=tmp_path, controllers=(ALL_CONTROLLERS, "optimal")).wants_optimal
    _, left_out = resolve_controllers(EvaluationConfig(out=tmp_path, controllers=(ALL_CONTROLLERS,)))
    assert set(names) | set(left_out) == set(available_policies())
    assert all(reason for reason in left_out.values())
    # the QP controllers run where the ik extra is installed, and are left out naming it where it is not
    for name in ("pink", "mink"):
        if importlib.util.find_spec(name) is not None:
            assert name in names
        else:
            assert f"{name} needs the 'ik' extra" in left_out[name], left_out
    # a name given with all is not repeated
    assert _names(EvaluationConfig(out=tmp_path, controllers=("mpc", ALL_CONTROLLERS)))[0] == "mpc"


def test_a_parameter_for_a_controller_outside_the_default_set_asks_for_its_name(tmp_path):
    config = EvaluationConfig(out=tmp_path, controller_kwargs={"mpc": {"horizon_s": 0.2}})
    with pytest.raises(ValueError, match=r"'mpc' is not among the evaluated controllers \(rnn, .*\); name it in"):
        resolve_controllers(config)
    assert _names(EvaluationConfig(out=tmp_path, controllers=("mpc",))) == ["mpc"]


def test_an_argument_the_controller_does_not_take_is_refused_by_name_before_anything_is_built(tmp_path):
    """Not the constructor's TypeError: the argument, the controller and what it does take; a class passing
    ``**kwargs`` to its base (snac-adaptive to snac-hjb) is checked against both."""
    import inspect

    from snac_gym.policies.registry import policy_factory

    def refusal(name: str, key: str) -> str:
        config = EvaluationConfig(out=tmp_path, controllers=(name,), controller_kwargs={name: {key: 1}})
        with pytest.raises(ValueError) as caught:
            resolve_controllers(config)
        return str(caught.value)

    for name in available_policies():
        message = refusal(name, "not_an_argument")
        own = [p for p in inspect.signature(policy_factory(name)).parameters if p not in ("env", "kwargs")]
        assert message.startswith(f"--param {name}.not_an_argument: {name!r} has no argument 'not_an_argument'; its")
        assert all(p in message.split("its arguments: ")[1].split(", ") for p in own), message
    assert refusal("mpc", "horizen").endswith("did you mean 'horizon'?")
    assert refusal("snac-adaptive", "learning_rat").endswith("did you mean 'learning_rate'?")  # snac-hjb's
    config = EvaluationConfig(out=tmp_path, controllers=("snac-adaptive",), controller_kwargs={"snac-adaptive": {
        "learning_rate": 0.5, "q_scale": 2.0}})  # fmt: skip
    (spec,) = resolve_controllers(config)[0]
    assert spec.kwargs == {"learning_rate": 0.5, "q_scale": 2.0}


def test_the_cli_help_names_the_default_set():
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    text = " ".join(CliRunner().invoke(app, ["evaluate", "--help"], env={"COLUMNS": "400"}).output.split())
    assert f"default: {','.join(DEFAULT_CONTROLLERS)}" in text, text


def test_a_controller_the_default_set_leaves_out_is_named_on_stderr_with_its_reason(tmp_path):
    """On the UR5e the shipped PPO (trained on the UR10) cannot run: the run goes on without it, summary.md lists it,
    and the console says so too, on stderr, where the summary's tables on stdout would not show it missing."""
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    out = tmp_path / "run"
    result = CliRunner().invoke(app, [
        "evaluate", "--robot", "ur5e", "--samples", "2", "--horizon", "0.2", "--no-match-effort", "--no-plots",
        "--no-progress", "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    notes = [line for line in result.stderr.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and re.fullmatch(
        r"note: ppo left out: .*trained on robot 'ur10' but the env's robot is 'ur5e'", notes[0]
    )
    assert "ppo" not in result.stdout.lower()
    assert f"- `ppo`: {notes[0].split('left out: ', 1)[1]}" in (out / "summary.md").read_text()
    # A run that leaves nothing out has no note.
    again = CliRunner().invoke(app, [
        "evaluate", "--controllers", "dls,lqr", "--samples", "2", "--horizon", "0.2", "--no-match-effort",
        "--no-plots", "--no-progress", "--out", str(tmp_path / "other"),
    ])  # fmt: skip
    assert again.exit_code == 0 and "note:" not in again.stderr, again.output
