"""Resuming a real run after a protective stop or a lost link, through the real ur_rtde client.

Each test runs ``run_real_episode`` (what ``snac-gym real`` does) against the emulated controller
(:class:`~snac_gym.real.emulator.process.EmulatorProcess`) with a fault scheduled after the first
``speedJ``, and checks the run's outcome and what the controller saw: its record of motion
commands that arrived while it reported a stop, or after the link came back before any state
package (``unsafe_commands``), holds at most the command already in flight when the stop hit.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from _loopback import emulator_host

pytest.importorskip("rtde_control")
pytestmark = pytest.mark.realtime

from snac_gym.apps.real import run_real_episode  # noqa: E402
from snac_gym.real import ConnectionFailure, SafetyLimits  # noqa: E402
from snac_gym.real.connections import PROTECTIVE_STOP_LOCKOUT  # noqa: E402
from snac_gym.real.emulator.process import EmulatorProcess  # noqa: E402
from snac_gym.real.recovery import RecoveryLimits  # noqa: E402

HOST = emulator_host()
#: Timing rules loosened: these tests are about resuming, and the host may be shared.
LOOSE_TIMING = SafetyLimits(max_stale_periods=25, max_period=0.5, max_missed_deadlines=25)
#: Longest delay (ms) after the controller reported a stop for a command already in flight to arrive.
IN_FLIGHT_MS = 100.0
#: The controller of these runs: the LQR law reaches within 1 mm of the reach demo's target in 2.6 s of
#: motion (`snac-gym demo --controller lqr`; SNAC takes 10 s), and from where it is 1 s in (‖e‖ about
#: 3 cm) in 2 s more, so an episode of 4 s at 125 Hz holds a fault 1 s in and the approach after it.
#: What is tested is the resuming, the same for every controller. No figures: they are tested elsewhere
#: (tests/realtime/test_emulator.py) and drawing them is most of a short run's CPU time.
CONTROLLER = "lqr"
STEPS = 500


def _final_error(result) -> float:
    return float(np.linalg.norm(result.demo.log[["e_0", "e_1", "e_2"]].to_numpy()[-1]))


def _assert_no_unsafe_command(emu: EmulatorProcess) -> None:
    """Only a command in flight when the stop hit may arrive during it; none before a fresh state."""
    for text in emu.status()["unsafe_commands"]:
        assert "before any state package" not in text, text
        delay = re.search(r"\(([\d.]+) ms after it was reported\)", text)
        assert "before it was reported" in text or (delay and float(delay.group(1)) <= IN_FLIGHT_MS), text


@pytest.mark.realtime(seconds=11)  # about this long here: run first (conftest.py)
def test_a_protective_stop_unlocked_after_5_s_resumes_and_the_episode_ends_within_1mm(emu, tmp_path):
    emu.schedule(1.0, "protective_stop")
    result = run_real_episode(
        task="reach", controller=CONTROLLER, out_dir=tmp_path, connection="rtde", host=HOST, steps=STEPS, plots=False,
        safety=LOOSE_TIMING, recovery=RecoveryLimits(max_recoveries=3, unlock_protective_stop=True),
    )  # fmt: skip
    assert result.stop_reason is None, result.stop_reason
    # on a busy host a client may also miss a deadline and be replaced (a "lost link" recovery)
    (recovery,) = [r for r in result.recoveries if r["kind"] == "protective stop"]
    assert recovery["kind"] == "protective stop" and recovery["cleared_by"] == "unlocked from the dashboard"
    assert PROTECTIVE_STOP_LOCKOUT <= recovery["gap_s"] < PROTECTIVE_STOP_LOCKOUT + 3.0
    assert _final_error(result) < 1e-3
    events = emu.status()["events"]
    assert "protective stop unlocked from the dashboard" in events
    assert not any(e.startswith("protective stop unlock refused") for e in events)  # the host waited out the 5 s
    _assert_no_unsafe_command(emu)
    # the gap is marked in the log and counted in the summary
    gaps = result.demo.log["resumed_after_s"].to_numpy()
    assert np.count_nonzero(~np.isnan(gaps)) == len(result.recoveries) and gaps[recovery["step"]] == recovery["gap_s"]
    assert f"protective stop before step {recovery['step']}, unlocked from the dashboard" in result.summary()
    assert recovery in json.loads((tmp_path / f"reach_{CONTROLLER}_real.json").read_text())["recoveries"]
    assert max(map(abs, emu.status()["qd"])) == 0.0  # stopped at the end


@pytest.mark.realtime(seconds=2)  # about this long here: run first (conftest.py)
def test_without_recoveries_a_protective_stop_ends_the_run_as_before(emu, tmp_path):
    emu.schedule(1.0, "protective_stop")
    # The same stop whether the host reads it first or the paused program refuses the speedJ in flight.
    result = run_real_episode(
        task="reach", controller=CONTROLLER, out_dir=tmp_path, connection="rtde", host=HOST, steps=STEPS, plots=False,
        safety=LOOSE_TIMING,
    )  # fmt: skip
    assert result.stop_reason == "controller reports protective_stop" and result.recoveries == []
    assert len(result.demo.log) < 200
    events = emu.status()["events"]
    assert not any("unlock" in e for e in events) and emu.status()["safety"] == "PROTECTIVE_STOP"
    _assert_no_unsafe_command(emu)


@pytest.mark.realtime(seconds=6)  # about this long here: run first (conftest.py)
def test_a_dropped_link_that_comes_back_is_reconnected_and_the_episode_ends_within_1mm(emu, tmp_path):
    emu.schedule(1.0, "drop_connection", 1.0)
    result = run_real_episode(
        task="reach", controller=CONTROLLER, out_dir=tmp_path, connection="rtde", host=HOST, steps=STEPS, plots=False,
        safety=LOOSE_TIMING, recovery=RecoveryLimits(max_recoveries=1),
    )  # fmt: skip
    assert result.stop_reason is None, result.stop_reason
    (recovery,) = result.recoveries
    assert recovery["kind"] == "lost link" and recovery["cleared_by"].startswith("reconnected")
    assert 1.0 <= recovery["gap_s"] < 10.0
    assert _final_error(result) < 1e-3
    events = emu.status()["events"]
    assert events.count("program rtde_control running (register offset 0)") == 2  # the script, uploaded again
    assert any(e.startswith("watchdog expired") for e in events)  # the controller stopped the arm meanwhile
    _assert_no_unsafe_command(emu)
    assert max(map(abs, emu.status()["qd"])) == 0.0


@pytest.mark.realtime(seconds=3)  # about this long here: run first (conftest.py)
def test_a_link_that_never_comes_back_ends_the_run_with_its_log(emu, tmp_path):
    emu.schedule(1.0, "drop_connection")
    with pytest.raises(ConnectionFailure, match="did not come back within 2 s") as raised:
        run_real_episode(
            task="reach", controller=CONTROLLER, out_dir=tmp_path, connection="rtde", host=HOST, steps=STEPS,
            plots=False, safety=LOOSE_TIMING, recovery=RecoveryLimits(max_recoveries=2, reconnect_timeout=2.0),
        )  # fmt: skip
    assert raised.value.log_dir == tmp_path
    summary = json.loads((tmp_path / f"reach_{CONTROLLER}_real.json").read_text())
    assert summary["ended"] == "link lost" and summary["recoveries"] == [] and summary["steps_logged"] > 100
    status = emu.status()
    assert max(map(abs, status["qd"])) == 0.0 and any(e.startswith("watchdog expired") for e in status["events"])
    emu.clear_faults()
