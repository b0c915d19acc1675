"""The rehearsals of ``snac-gym real`` (``--connection sim``, ``--dry-run``) finish on a busy host: missed
deadlines are counted and reported, not stopped on, unless ``--deadline-stop`` asks for the stop; a real or
emulated arm (``--connection rtde``) keeps it.

Lateness is injected, not hoped for: the simulated connection sleeps on chosen periods, so those periods are
late (and one stalls) however idle the host is.
"""

from __future__ import annotations

import json
import time

import pandas as pd
import pytest
from typer.testing import CliRunner

import snac_gym.apps.real as real_run
from snac_gym.apps.cli import app
from snac_gym.real import SafetyLimits, SimulatedConnection
from snac_gym.real.safety import SafetyLayer

STEPS = 20
#: Extra seconds slept at the end of these periods: 8 ms + 10 ms is late (over 1.5 × 8 ms), 8 ms + 50 ms a stall.
DELAYS = {3: 0.010, 4: 0.010, 5: 0.010, 8: 0.010, 10: 0.050, 12: 0.010, 14: 0.010}
REHEARSALS = [["--connection", "sim"], ["--connection", "sim", "--dry-run"]]


@pytest.fixture
def late_periods(monkeypatch):
    """Every :class:`SimulatedConnection` sleeps :data:`DELAYS` at the end of those periods."""
    original = SimulatedConnection.end_period

    def end_period(self, period_start):
        original(self, period_start)
        self.periods_ended = getattr(self, "periods_ended", 0) + 1
        time.sleep(DELAYS.get(self.periods_ended, 0.0))

    monkeypatch.setattr(SimulatedConnection, "end_period", end_period)


def _real(tmp_path, *extra: str):
    return CliRunner().invoke(app, [
        "real", "--controller", "dls", "--steps", str(STEPS), "--no-plots", "--out", str(tmp_path), *extra,
    ])  # fmt: skip


@pytest.mark.slow(seconds=3)
@pytest.mark.parametrize("extra", REHEARSALS, ids=["sim", "dry-run"])
def test_a_rehearsal_with_missed_deadlines_finishes_and_reports_them(tmp_path, late_periods, extra):
    result = _real(tmp_path, *extra)
    assert result.exit_code == 0, result.output
    assert "no safety stop" in result.output
    line = next(line for line in result.output.splitlines() if line.strip().startswith("late periods"))
    late = int(line.split()[2])
    assert late >= len(DELAYS)
    assert f"of {STEPS} (worst " in line and "stalled" in line and "counted only" in line
    record = json.loads((tmp_path / "reach_dls_real.json").read_text())
    assert record["late_periods"].startswith(f"{late} of {STEPS} (worst ") and record["stop_reason"] is None
    assert record["setup"]["deadline_stop"] is False and record["timing"]["stalled_periods"] >= 1
    log = pd.read_parquet(tmp_path / "reach_dls_log.parquet")
    assert len(log) == STEPS and log.attrs["deadline_stop"] is False
    assert log.attrs["late_periods"] == record["late_periods"]


@pytest.mark.slow(seconds=2)
@pytest.mark.parametrize("extra", REHEARSALS, ids=["sim", "dry-run"])
def test_a_rehearsal_opts_into_the_deadline_stop(tmp_path, late_periods, extra):
    result = _real(tmp_path, *extra, "--deadline-stop")
    assert result.exit_code == 4, result.output
    assert "stopped by safety layer: control loop" in result.output
    assert json.loads((tmp_path / "reach_dls_real.json").read_text())["setup"]["deadline_stop"] is True


@pytest.mark.slow(seconds=2)
def test_a_real_or_emulated_arm_still_stops_on_missed_deadlines(monkeypatch, tmp_path, late_periods):
    """``--connection rtde`` (here the simulated arm behind it, as a controller would be): the stop is on."""
    monkeypatch.setattr(real_run, "make_connection", lambda *args, **kwargs: SimulatedConnection())
    result = _real(tmp_path, "--host", "10.0.0.2")
    assert result.exit_code == 4, result.output
    assert "stopped by safety layer: control loop" in result.output
    assert "counted only" not in result.output


def test_the_deadline_stop_cannot_be_turned_off_for_a_real_arm(tmp_path):
    result = _real(tmp_path, "--host", "192.0.2.1", "--no-deadline-stop")
    assert result.exit_code == 2, result.output
    assert "--no-deadline-stop is for a rehearsal (--connection sim or --dry-run)" in result.output


@pytest.mark.parametrize(
    ("connection", "dry_run", "asked", "stop"),
    [
        ("sim", False, None, False),
        ("sim", True, None, False),
        ("rtde", True, None, False),  # a dry run against the arm sends nothing
        ("rtde", False, None, True),
        ("sim", False, True, True),
        ("rtde", True, True, True),
        ("sim", False, False, False),
    ],
)
def test_the_deadline_stop_is_on_for_an_arm_that_moves_and_off_for_a_rehearsal(connection, dry_run, asked, stop):
    limits = real_run.resolve_deadline_stop(SafetyLimits(), connection, dry_run, asked)
    assert limits.deadline_stop is stop
    with pytest.raises(ValueError, match="--no-deadline-stop is for a rehearsal"):
        real_run.resolve_deadline_stop(SafetyLimits(deadline_stop=False), "rtde", False, None)


def test_without_the_deadline_stop_the_layer_counts_but_never_stops():
    connection = SimulatedConnection(realtime=False)
    for deadline_stop in (True, False):
        layer = SafetyLayer(connection.kinematics, SafetyLimits(deadline_stop=deadline_stop), connection.dt)
        messages = [layer.record_period(0.02) for _ in range(3)] + [layer.stall(0.5), layer.record_period(0.5)]
        if deadline_stop:
            assert messages[2].startswith("control loop missed") and messages[3].startswith("control loop stalled")
        else:
            assert messages == [None] * 5 and sum(layer._late_flags) == 4
    connection.close()
    with pytest.raises(ValueError, match="deadline_stop must be True or False"):
        SafetyLimits(deadline_stop="no")
