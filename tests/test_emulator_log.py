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
    (usual,), (stalled,) = ([r for r in caplog.records if "watchdog expired" in r.getMessage() and k in r.getMessage()]
                            for k in ("closed the link", "stalled host"))
    assert usual.levelno == logging.INFO and "the usual end of a run, not a fault" in usual.getMessage()
    assert stalled.levelno == logging.WARNING and "no update of input_int_register_0 for 0.046 s" in stalled.getMessage()
    assert emulator.runtime_state == p.RUNTIME_STOPPED
