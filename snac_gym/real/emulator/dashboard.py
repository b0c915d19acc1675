"""The emulated controller's dashboard server: its answer to each request line.

A layer of :class:`~snac_gym.real.emulator.controller.UREmulator` (see :mod:`~snac_gym.real.emulator.state`);
:func:`~snac_gym.real.emulator.servers.serve_dashboard` reads the lines and writes the answers.
"""

from __future__ import annotations

import time

from snac_gym.real.connections import PROTECTIVE_STOP_LOCKOUT
from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.faults import Faults

__all__ = ["UNLOCK_TOO_EARLY", "DashboardAnswers"]

#: The dashboard's answer to ``unlock protective stop`` within the lockout (PolyScope's wording).
UNLOCK_TOO_EARLY = (
    f"Cannot unlock protective stop until {PROTECTIVE_STOP_LOCKOUT:g}s after occurrence. "
    "Always inspect cause of protective stop before unlocking"
)


class DashboardAnswers(Faults):
    """The dashboard's answers, PolyScope's wording."""

    # ----------------------------------------------------------------- dashboard
    def dashboard(self, request: str) -> str:
        """The dashboard server's answer to one request line."""
        major, minor, bugfix, build = self.version
        with self.lock:
            answers = {
                "PolyscopeVersion": f"URSoftware {major}.{minor}.{bugfix}.{build} (emulated)",
                "get serial number": "20235500001",
                "get robot model": self.arm.robot.upper(),
                "is in remote control": "true",
                "robotmode": "Robotmode: RUNNING",
                "safetystatus": f"Safetystatus: {self._safety_name()}",
                "safetymode": f"Safetymode: {self._safety_name()}",
                "running": f"Program running: {str(self.runtime_state == p.RUNTIME_PLAYING).lower()}",
                "programState": f"{self._program_state()} {self.programs[-1] if self.programs else '<unnamed>'}",
                "close safety popup": "closing safety popup",
                "quit": "Disconnected",
            }
            if request in answers:
                return answers[request]
            if request == "stop":
                if self.runtime_state != p.RUNTIME_STOPPED:
                    self._end_program("program stopped from the dashboard")
                return "Stopped"
            if request == "unlock protective stop":
                return self._unlock_protective_stop()
        return f"could not understand: '{request}'"

    def _unlock_protective_stop(self) -> str:
        """PolyScope's rule: a protective stop can be unlocked only 5 s after it occurred."""
        if self._safety_name() != "PROTECTIVE_STOP":
            return "Cannot unlock protective stop"
        if time.monotonic() - self._protective_stop_at < PROTECTIVE_STOP_LOCKOUT:
            self.event("protective stop unlock refused: within the 5 s lockout")
            return UNLOCK_TOO_EARLY
        self._release_safety()
        self.event("protective stop unlocked from the dashboard")
        return "Protective stop releasing"
