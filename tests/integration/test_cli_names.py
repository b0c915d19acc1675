"""The three meanings of "backend", named apart on the command line: --engine (evaluate), --connection (real).

``--backend`` stays as a hidden, deprecated name of each; the env's is ``physics=`` (tests/envs/test_ids.py).
"""

import pytest
from typer.testing import CliRunner

from snac_gym.apps.cli import app


@pytest.fixture
def captured_config(monkeypatch):
    """``snac-gym evaluate --export-only``, with the config it builds captured instead of written out."""
    import snac_gym.evaluation.runner

    seen = {}

    def export(config):
        seen["config"] = config
        return "samples.csv"

    monkeypatch.setattr(snac_gym.evaluation.runner, "export_sample_set", export)
    return seen


def _evaluate(tmp_path, *options):
    return CliRunner().invoke(
        app,
        [
            "evaluate",
            "--out",
            str(tmp_path / "run"),
            "--samples",
            "2",
            "--export-samples",
            str(tmp_path / "s.csv"),
            "--export-only",
            "--no-progress",
            *options,
        ],
    )


def test_evaluate_names_its_engine(tmp_path, captured_config):
    outcome = _evaluate(tmp_path, "--engine", "pybullet")
    assert outcome.exit_code == 0, outcome.output
    assert captured_config["config"].engine == "pybullet"
    assert _evaluate(tmp_path).exit_code == 0 and captured_config["config"].engine == "kinematic"


def test_evaluate_backend_is_a_hidden_deprecated_name_of_engine(tmp_path, captured_config):
    with pytest.warns(DeprecationWarning, match="--backend is deprecated; use --engine"):
        outcome = _evaluate(tmp_path, "--backend", "pybullet")
    assert outcome.exit_code == 0, outcome.output
    # At the shell, where Python hides a DeprecationWarning, the command says it on stderr.
    assert "snac-gym: warning: --backend is deprecated; use --engine" in outcome.stderr
    assert captured_config["config"].engine == "pybullet"
    with pytest.warns(DeprecationWarning):
        clash = _evaluate(tmp_path, "--engine", "pybullet", "--backend", "kinematic")
    flat = " ".join(clash.output.replace("│", " ").split())  # the error panel wraps lines
    assert clash.exit_code == 2 and "give --engine only (--backend is its deprecated name)" in flat
    help_text = CliRunner().invoke(app, ["evaluate", "--help"]).output
    assert "--engine" in help_text and "--backend" not in help_text


def test_real_names_its_connection(monkeypatch, tmp_path):
    import snac_gym.apps.real as real_run

    calls = []

    def run(**kwargs):
        calls.append(kwargs["connection"])
        raise ValueError("stopped by the test")

    monkeypatch.setattr(real_run, "run_real_episode", run)
    assert CliRunner().invoke(app, ["real", "--connection", "sim", "--out", str(tmp_path)]).exit_code == 2
    with pytest.warns(DeprecationWarning, match="--backend is deprecated; use --connection"):
        renamed = CliRunner().invoke(app, ["real", "--backend", "sim", "--out", str(tmp_path)])
    assert renamed.exit_code == 2
    assert "snac-gym: warning: --backend is deprecated; use --connection" in renamed.stderr
    assert calls == ["sim", "sim"]
    help_text = CliRunner().invoke(app, ["real", "--help"]).output
    assert "--connection" in help_text and "--backend" not in help_text


def test_the_real_arm_connections_keep_their_former_names_with_a_warning():
    import snac_gym.real as real

    for old, new in [
        ("ArmBackend", "ArmConnection"),
        ("URRTDEBackend", "URRTDEConnection"),
        ("SimulatedBackend", "SimulatedConnection"),
        ("DryRunBackend", "DryRunConnection"),
    ]:
        with pytest.warns(DeprecationWarning, match=f"snac_gym.real.{old} is deprecated; use snac_gym.real.{new}"):
            assert getattr(real, old) is getattr(real, new)
        assert old not in real.__all__
    with pytest.raises(AttributeError, match="no attribute 'Backend'"):
        real.Backend  # noqa: B018


def test_every_option_name_is_whole_in_the_help_at_80_columns():
    """No "--unlock-protectiv…": each command's help, 80 columns wide, spells every visible option out."""
    import typer.main

    group = typer.main.get_command(app)
    for name, command in group.commands.items():
        text = CliRunner().invoke(app, [name, "--help"], terminal_width=80, env={"COLUMNS": "80"}).output
        assert "…" not in text and max(map(len, text.splitlines())) <= 80, name
        for param in command.params:
            if getattr(param, "hidden", False):
                continue
            for option in [*param.opts, *getattr(param, "secondary_opts", [])]:
                if option.startswith("--"):
                    assert option in text, (name, option)
