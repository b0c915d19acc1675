"""The emulated controller's log: a watchdog expiry after the client closed its link is the usual end of a run
(INFO); one while a client is still connected is a stalled host (WARNING). No sockets: the watchdog is driven
by hand."""

import logging
import types

from snac_gym.real.emulator import UREmulator
from snac_gym.real.emulator import protocol as p


def _expire(emulator: UREmulator, owner_closed: bool) -> None:
    emulator.runtime_state = p.RUNTIME_PLAYING
    emulator.set_watchdog(25.0, "input_int_register_0")
    emulator._input_owner["input_int_register_0"] = types.SimpleNamespace(closed=owner_closed)
    now = emulator._watch_update + 0.046
    emulator._last_cycle = now - emulator.dt  # a regular cycle, not a descheduled emulator
    emulator._check_watchdog(now)


def test_the_watchdog_after_a_closed_link_is_info_and_with_a_connected_client_a_warning(caplog):
    emulator = UREmulator(robot="ur5", port_base=0)
    with caplog.at_level(logging.INFO, logger="snac_gym.emulate_ur"):
        _expire(emulator, owner_closed=True)
        _expire(emulator, owner_closed=False)
    (usual,), (stalled,) = (
        [r for r in caplog.records if "watchdog expired" in r.getMessage() and k in r.getMessage()]
        for k in ("closed the link", "stalled host")
    )
    assert usual.levelno == logging.INFO and "the usual end of a run, not a fault" in usual.getMessage()
    assert (
        stalled.levelno == logging.WARNING and "no update of input_int_register_0 for 0.046 s" in stalled.getMessage()
    )
    assert emulator.runtime_state == p.RUNTIME_STOPPED


def test_a_fault_with_a_bad_argument_is_refused_when_it_is_scheduled():
    """`--latency-spike 1,-3` used to kill the control cycle when the fault came due (and the process exited 0)."""
    import pytest

    from snac_gym.real.emulator.serve import fault_plan

    emulator = UREmulator(robot="ur10", port_base=0)
    for at, fault, args in fault_plan(latency_spike="1,0.2", drop_at=2.0, drop_for=1.0):
        emulator.schedule(at, fault, *args)
    for fault, args, message in [
        ("latency_spike", (-3.0,), "latency spike must be a non-negative number of seconds, got -3.0"),
        ("latency_spike", (float("nan"),), "latency spike must be a non-negative number of seconds"),
        ("drop_connection", (-1.0,), "refuse_for must be a non-negative number of seconds, got -1.0"),
    ]:
        with pytest.raises(ValueError, match=message):
            emulator.schedule(1.0, fault, *args)
    assert len(emulator._scheduled) == 2


def test_a_thread_that_dies_stops_the_emulator_and_the_command_exits_1(monkeypatch):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    def broken_cycle(self):
        raise RuntimeError("a fault in the cycle")

    monkeypatch.setattr(UREmulator, "_control_cycle", broken_cycle)
    result = CliRunner().invoke(app, ["emulate-ur", "--port-base", "0", "--duration", "30"])
    assert result.exit_code == 1, result.output
    assert "error: the emulator stopped: RuntimeError: a fault in the cycle" in result.output
