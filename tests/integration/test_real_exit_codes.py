"""`snac-gym real`'s exit codes, one per way a run ends (its --help and docs/real-arm.md list them)."""

from __future__ import annotations

import signal
import types

import pytest
from typer.testing import CliRunner

import snac_gym.apps.real as real_run
from snac_gym.apps.cli import app
from snac_gym.real import ConnectionFailure


def _result(stop_reason: str | None, rest: dict | None = None) -> real_run.RealRunResult:
    return real_run.RealRunResult(
        demo=types.SimpleNamespace(summary=lambda: "demo figures"), timing={}, stop_reason=stop_reason, rest=rest or {}
    )


STALE = "stale joint state: the controller's timestamp stayed at 6.464000 s for 3 periods running"
UNCONFIRMED = {
    "rest_confirmed": False, "stopped_by": "speedStop, then stopScript (host)",
    "rest_not_confirmed": "nothing confirmed the arm at rest within 2 s: RTDE stale state; dashboard unreachable",
}  # fmt: skip
CONFIRMED = {
    "rest_confirmed": True, "rest_confirmed_after_s": 0.19, "stopped_by": "speedStop, then stopScript (host)",
    "rest_confirmed_by": "dashboard: programState STOPPED rtde_control, robotmode RUNNING, safetystatus NORMAL",
}  # fmt: skip


def _invoke(monkeypatch, outcome, tmp_path, *extra: str):
    def fake(**kwargs):
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome

    monkeypatch.setattr(real_run, "run_real_episode", fake)
    return CliRunner().invoke(app, ["real", "--connection", "sim", "--out", str(tmp_path), *extra])


@pytest.mark.parametrize(
    ("outcome", "code", "line"),
    [
        (_result(None), 0, "no safety stop"),
        (
            _result("tool left the task box: x = [0.1, 0.2, 0.3] m"),
            4,
            "stopped by safety layer: tool left the task box",
        ),
        (
            _result("controller reports protective_stop"),
            5,
            "stopped by safety layer: controller reports protective_stop",
        ),
        (_result("controller reports emergency_stop"), 6, "stopped by safety layer: controller reports emergency_stop"),
        (
            _result(STALE, CONFIRMED),
            4,
            "at rest                     confirmed after 0.19 s by dashboard: programState STOPPED",
        ),
        (_result(STALE, UNCONFIRMED), 7, "NOT confirmed at rest: nothing confirmed the arm at rest within 2 s"),
        (_result(None, UNCONFIRMED), 7, "NOT confirmed at rest"),
        (ConnectionFailure("the link to 10.0.0.2 was lost"), 1, "error: the link to 10.0.0.2 was lost"),
        (OSError("disk full"), 3, "error: unexpected OSError: disk full"),
        (KeyboardInterrupt(), 130, "interrupted by SIGINT: the arm was stopped"),
        (real_run.TerminationSignal(signal.SIGTERM), 143, "interrupted by SIGTERM: the arm was stopped"),
    ],
    ids=[
        "finished",
        "safety-stop",
        "protective-stop",
        "emergency-stop",
        "stale-rest-confirmed",
        "stale-rest-not-confirmed",
        "finished-rest-not-confirmed",
        "link-lost",
        "unexpected",
        "sigint",
        "sigterm",
    ],
)
def test_each_way_a_run_ends_has_its_exit_code(monkeypatch, tmp_path, outcome, code, line):
    result = _invoke(monkeypatch, outcome, tmp_path)
    assert result.exit_code == code, result.output
    assert line in result.output


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            ["--robot", "panda"],
            "Invalid value for --robot: 'panda' is not a UR model; choose one of ur3, ur5, ur10, ur3e, ur5e, "
            "ur10e, ur16e",
        ),
        (["--robot", "ur10", "--series", "e"], "--series e is the e-Series' 500 Hz; the UR10 is a CB3 arm (125 Hz)"),
        (["--robot", "ur5e", "--series", "x"], "--series must be one of cb, e, got 'x'"),
        (["--q0", "1,2,3"], "--q0 needs 6 finite numbers separated by commas, got '1,2,3'"),
        (["--target", "0.1,nan,0.2"], "--target needs 3 finite numbers separated by commas"),
        (["--target", "3,3,3"], "--target: point [3.0, 3.0, 3.0] m is outside the reachable workspace of ur10"),
        (
            ["--robot", "ur5"],
            "(the paper's start pose and reference are the UR10's: give --q0 and the reference for ur5; "
            "--target=-0.456,0.434,0.282 is the paper's scaled to the UR5, as `snac-gym demo --robot ur5` runs it)",
        ),
        (["--task", "track", "--target", "0,0,0"], "--target is for --task reach"),
        (["--task-box", "0,0,0,1,1"], "--task-box needs 6 finite numbers"),
        (
            ["--task-box", "-1,0.2,0.2,-0.5,0.5,0.5"],
            "the reach reference leaves the task box [-1.000, 0.200, 0.200] .. [-0.500, 0.500, 0.500] m at "
            "[-0.658, 0.626, 0.407]",
        ),
        (["--joint-margin", "2"], "joint_limit_margin must be a finite number in [0, 1.5708], got 2.0"),
        (["--q0", "0,0,0,0,0,0"], "--q0 is outside the safety limits"),
    ],
)
def test_a_refused_input_exits_2_before_anything_connects(tmp_path, arguments, message):
    """Checked by run_setup before the connection is made: no arm, no emulator needed (a real rtde host here
    would be an error of its own, exit 1)."""
    result = CliRunner().invoke(
        app, ["real", "--connection", "rtde", "--host", "192.0.2.1", "--out", str(tmp_path), *arguments]
    )
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_a_dry_run_prints_and_records_the_setup(tmp_path):
    out = tmp_path / "dry"
    result = CliRunner().invoke(app, [
        "real", "--connection", "sim", "--dry-run", "--steps", "20", "--no-plots", "--out", str(out),
        "--q0", "-0.51,-1.04,1.48,-1.82,-1.45,-1.62", "--target", "-0.6,0.5,0.45",
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (
        'setup: {"robot": "ur10", "task": "reach", "q0": [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62], '
        '"target": [-0.6, 0.5, 0.45]' in result.output
    )
    import json

    setup = json.loads((out / "reach_snac_real.json").read_text())["setup"]
    assert setup["target"] == [-0.6, 0.5, 0.45] and setup["joint_limit_margin"] == 0.1 and len(setup["task_box"]) == 2
