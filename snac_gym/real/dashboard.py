"""The UR controller's dashboard server, asked over a plain socket: its answers, and the confirmation that the
arm is at rest after a stop (:class:`~snac_gym.real.connections.URRTDEConnection`)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Sequence

__all__ = [
    "DASHBOARD_PORT",
    "DASHBOARD_REST_REQUESTS",
    "HELD_ROBOT_MODES",
    "ask_dashboard",
    "confirm_rest_by_dashboard",
]

#: The dashboard server's port on a UR controller (PolyScope's, fixed).
DASHBOARD_PORT = 29999
#: Robot modes (the dashboard's ``robotmode``) in which an arm whose program is stopped is held at rest by the
#: controller (position held, or brakes on). Not BACKDRIVE (the arm moves by hand), BOOTING, CONFIRM_SAFETY,
#: NO_CONTROLLER, DISCONNECTED or UPDATING_FIRMWARE: there the answer says nothing of rest.
HELD_ROBOT_MODES = frozenset({"RUNNING", "IDLE", "POWER_ON", "POWER_OFF"})
#: What the dashboard is asked to confirm rest (UR dashboard server: ``programState`` answers ``STOPPED <program>``,
#: ``PAUSED <program>`` or ``PLAYING <program>``; ``robotmode`` ``Robotmode: RUNNING``; ``safetystatus``
#: ``Safetystatus: NORMAL`` (software 3.11 and 5.4 onwards; older ones do not understand it, which is kept as said).
DASHBOARD_REST_REQUESTS = ("programState", "robotmode", "safetystatus")


def ask_dashboard(host: str, requests: Sequence[str], timeout: float, port: int = DASHBOARD_PORT) -> dict[str, str]:
    """One connection to the controller's dashboard server: each request's one-line answer.

    A plain socket with ``timeout`` s per operation (not ur_rtde), so that it answers from the host's own
    process whether or not the ur_rtde client still serves.

    Raises:
        OSError: Refused, unreachable, timed out, or closed before every answer came.
    """
    answers: dict[str, str] = {}
    with socket.create_connection((host, port), timeout=timeout) as sock:
        reader = sock.makefile("rb")
        if not reader.readline():  # the welcome line
            raise ConnectionError("the dashboard server closed the connection")
        for request in requests:
            sock.sendall(request.encode() + b"\n")
            line = reader.readline()
            if not line:
                raise ConnectionError(f"the dashboard server closed the connection before answering {request!r}")
            answers[request] = line.decode(errors="replace").strip()
    return answers


def _dashboard_word(answer: str, prefix: str) -> str:
    """``Robotmode: RUNNING`` -> ``RUNNING``; an answer without ``prefix`` (not understood) as it came."""
    head, sep, rest = answer.partition(":")
    return rest.strip() if sep and head.strip().lower() == prefix else answer


def confirm_rest_by_dashboard(
    ask: Callable[[Sequence[str]], dict[str, str]],
    within: float,
    settle: float,
    poll: float = 0.05,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[bool, str]:
    """Whether the dashboard server confirms the arm at rest within ``within`` s, and what it said.

    Rest is confirmed by two answers ``settle`` s apart (the controller's own stop ramp from the
    arm's last known speed), each with the program not running (``programState`` ``STOPPED`` or
    ``PAUSED``: nothing drives the arm) and the robot in a mode that holds it
    (:data:`HELD_ROBOT_MODES`). ``ask(requests)`` returns the answers or raises ``OSError``
    (unreachable); it is asked every ``poll`` s until then.

    Returns:
        ``(True, "dashboard: programState STOPPED …, robotmode RUNNING, safetystatus NORMAL")`` or
        ``(False, the last thing that kept it from confirming)``.
    """
    start = clock()
    stopped_since: float | None = None
    problem = "not asked"
    while True:
        try:
            answers = ask(DASHBOARD_REST_REQUESTS)
        except OSError as exc:
            problem, stopped_since = f"dashboard unreachable ({type(exc).__name__}: {exc})", None
        else:
            program = answers.get("programState", "")
            mode = _dashboard_word(answers.get("robotmode", ""), "robotmode")
            safety = _dashboard_word(answers.get("safetystatus", ""), "safetystatus")
            said = f"programState {program}, robotmode {mode}, safetystatus {safety}"
            if program.split(" ", 1)[0] in ("STOPPED", "PAUSED") and mode in HELD_ROBOT_MODES:
                now = clock()
                stopped_since = now if stopped_since is None else stopped_since
                if now - stopped_since >= settle:
                    return True, f"dashboard: {said}"
                problem = f"dashboard: {said}, not yet {settle:.2f} s (the stop ramp) after it first said so"
            else:
                problem, stopped_since = f"dashboard: {said}: the program still runs or the arm is not held", None
        if clock() - start >= within:
            return False, problem
        sleep(poll)
