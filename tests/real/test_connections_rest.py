"""Confirming the arm at rest after a stop, through a source that is not the stale one (no ur_rtde, no real time).

:func:`~snac_gym.real.connections.confirm_rest_by_dashboard` with a fake dashboard that answers, answers late,
or never answers; :meth:`~snac_gym.real.connections.URRTDEConnection.stop` with a fake ur_rtde client (RTDE at
rest, RTDE frozen, client gone); and the emulated controller's dashboard answers, read by
:func:`~snac_gym.real.connections.ask_dashboard` over its socket.
"""

from __future__ import annotations

from typing import Any

import pytest

import snac_gym.real.connections as connections
from snac_gym.real.connections import URRTDEConnection, ask_dashboard, confirm_rest_by_dashboard
from snac_gym.real.emulator.controller import UREmulator

STOPPED = {
    "programState": "STOPPED rtde_control",
    "robotmode": "Robotmode: RUNNING",
    "safetystatus": "Safetystatus: NORMAL",
}


class Clock:
    """A fake monotonic clock that ``sleep`` advances."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def _confirm(answers: list[Any], within: float = 2.0, settle: float = 0.1) -> tuple[bool, str, float, int]:
    """Run the confirmation against a dashboard answering ``answers`` in turn (the last one from then on;
    an exception is raised as the dashboard's failure)."""
    clock, asked = Clock(), []

    def ask(requests):
        assert tuple(requests) == ("programState", "robotmode", "safetystatus")
        answer = answers[min(len(asked), len(answers) - 1)]
        asked.append(answer)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    confirmed, said = confirm_rest_by_dashboard(ask, within, settle, clock=clock, sleep=clock.sleep)
    return confirmed, said, clock.now, len(asked)


def test_a_stopped_program_on_a_held_arm_confirms_rest_after_the_stop_ramp():
    confirmed, said, took, asked = _confirm([STOPPED], settle=0.1)
    assert confirmed and said == "dashboard: programState STOPPED rtde_control, robotmode RUNNING, safetystatus NORMAL"
    assert took == pytest.approx(0.1) and asked == 3  # two answers the ramp apart (0.05 s polls)


def test_a_dashboard_that_never_answers_confirms_nothing_and_says_so_within_its_bound():
    confirmed, said, took, _ = _confirm([ConnectionRefusedError(111, "Connection refused")], within=2.0)
    assert not confirmed and said.startswith("dashboard unreachable (ConnectionRefusedError")
    assert 2.0 <= took < 2.1


def test_a_running_program_or_an_arm_not_held_is_not_rest():
    confirmed, said, took, _ = _confirm([{**STOPPED, "programState": "PLAYING rtde_control"}], within=1.0)
    assert not confirmed and "programState PLAYING rtde_control" in said and "still runs" in said and took >= 1.0
    confirmed, said, _, _ = _confirm([{**STOPPED, "robotmode": "Robotmode: BACKDRIVE"}], within=1.0)
    assert not confirmed and "robotmode BACKDRIVE" in said


def test_rest_is_confirmed_once_the_program_stops_and_a_refusal_restarts_the_count():
    running = {**STOPPED, "programState": "PLAYING rtde_control"}
    confirmed, said, took, _ = _confirm([running, running, STOPPED, OSError("reset"), STOPPED], settle=0.1)
    assert confirmed and "STOPPED" in said
    # stopped at 0.1 s, refused at 0.15 s, stopped again from 0.2 s: confirmed 0.1 s later (a poll more: rounding)
    assert 0.3 - 1e-9 <= took <= 0.35 + 1e-9


def test_an_old_controller_without_safetystatus_still_confirms_and_says_what_it_answered():
    old = {**STOPPED, "safetystatus": "could not understand: 'safetystatus'"}
    confirmed, said, _, _ = _confirm([old])
    assert confirmed and said.endswith("safetystatus could not understand: 'safetystatus'")


# ---------------------------------------------------------------------------- URRTDEConnection.stop


class FakeClient:
    """The ur_rtde client process, answering each request from ``replies`` (name -> payload)."""

    replies: dict[str, Any] = {}

    def __init__(self) -> None:
        self.failure: str | None = None
        self.output: list[str] = []
        self.pid = 0
        self.calls: list[str] = []

    def call(self, name: str, args: tuple[object, ...], timeout: float) -> tuple[str, Any]:
        self.calls.append(name)
        if name in ("connect", "state"):
            state = {"q": [0.0] * 6, "qd": [0.3, 0, 0, 0, 0, 0], "tcp": [0.0] * 6, "scaling": 1.0, "stamp": 1.0,
                     "safety": "normal"}  # fmt: skip
            return "ok", state
        return "ok", self.replies[name]

    def abandon(self, reason: str) -> None:
        self.failure = self.failure or reason

    def close(self, timeout: float) -> None:
        pass


@pytest.fixture
def arm(monkeypatch):
    """A URRTDEConnection over :class:`FakeClient`, a stream sent; the dashboard is ``arm.dashboard``
    (answers, or an exception to raise)."""
    monkeypatch.setattr(connections, "require_installed", lambda *args: None)  # the fake client needs no ur_rtde
    monkeypatch.setattr(connections, "probe_port", lambda *args: None)
    monkeypatch.setattr(connections, "ClientProcess", FakeClient)
    FakeClient.replies = {"command": True, "stop_script": "control script stopped"}
    connection = URRTDEConnection("192.0.2.7", confirm_timeout=0.3, stop_deceleration=2.0)
    asked: list[str] = []

    def ask(host, requests, timeout):
        asked.append(host)
        if isinstance(connection.dashboard, BaseException):
            raise connection.dashboard
        return connection.dashboard

    monkeypatch.setattr(connections, "ask_dashboard", ask)
    connection.dashboard, connection.asked = STOPPED, asked  # type: ignore[attr-defined]
    connection.command([0.3, 0, 0, 0, 0, 0])
    return connection


def test_rest_read_from_a_fresh_rtde_package_is_recorded_as_rtde_and_the_dashboard_is_not_asked(arm):
    FakeClient.replies["stop"] = "at rest"
    arm.stop()
    record = arm.stop_record()
    assert record["rest_confirmed"] and record["rest_confirmed_by"].startswith("rtde: joint speeds under")
    assert record["stopped_by"] == "speedStop (host)" and arm.asked == []
    assert "stop_script" not in arm._client.calls


def test_a_frozen_state_stops_the_script_and_the_dashboard_confirms_rest(arm):
    FakeClient.replies["stop"] = (
        "stale state: the controller's timestamp stayed at 1.000000 s for 105 ms after speedStop"
    )
    arm.stop()
    record = arm.stop_record()
    assert arm._client.calls[-2:] == ["stop", "stop_script"]  # speedStop, then stopScript
    assert record["rest_confirmed"] is True and record["rest_not_confirmed"] is None
    assert (
        record["rest_confirmed_by"]
        == "dashboard: programState STOPPED rtde_control, robotmode RUNNING, safetystatus NORMAL"
    )
    assert record["stopped_by"].startswith("speedStop, then stopScript (host)")
    assert record["stop_ramp_s"] == pytest.approx(0.15)  # 0.3 rad/s at 2 rad/s²
    assert 0.15 <= record["rest_confirmed_after_s"] < 0.3 + 0.2 and arm.asked[0] == "192.0.2.7"
    calls = len(arm._client.calls)
    arm.stop()  # nothing sent since: the record holds, nothing more is sent or asked
    assert len(arm._client.calls) == calls and arm.stop_record() == record


def test_when_nothing_confirms_rest_the_record_says_exactly_that(arm):
    FakeClient.replies["stop"] = (
        "stale state: the controller's timestamp stayed at 1.000000 s for 105 ms after speedStop"
    )
    arm.dashboard = ConnectionRefusedError(111, "Connection refused")
    arm.stop()
    record = arm.stop_record()
    assert record["rest_confirmed"] is False and record["rest_confirmed_by"] is None
    assert record["rest_not_confirmed"].startswith("nothing confirmed the arm at rest within 0.3 s: RTDE stale state")
    assert "dashboard unreachable (ConnectionRefusedError" in record["rest_not_confirmed"]
    assert 0.3 <= record["stop_took_s"] < 1.0


def test_a_client_gone_leaves_the_stop_to_the_controllers_watchdog_and_the_record_names_it(arm):
    arm._client.failure = "connection to the arm at 192.0.2.7 was lost"
    arm.dashboard = ConnectionRefusedError(111, "Connection refused")
    arm.stop()
    record = arm.stop_record()
    assert arm.last_stop == "client gone: left to the controller's watchdog"
    assert (
        record["stopped_by"]
        == "the controller's watchdog: no command for 40 ms (5 periods) stops the program and the arm"
    )
    assert record["watchdog_period_s"] == pytest.approx(0.04) and record["client_gone"] and record["watchdog_armed"]
    assert record["rest_confirmed"] is False and "dashboard unreachable" in record["rest_not_confirmed"]
    assert "stop" not in arm._client.calls and "stop_script" not in arm._client.calls


# ---------------------------------------------------------------------------- the emulator's dashboard


def test_the_emulated_dashboard_answers_as_a_ur_controller_does():
    with UREmulator(robot="ur5", port_base=0, bind_timeout=5.0) as emulator:
        port = emulator.ports["dashboard"]
        answers = ask_dashboard("127.0.0.1", ("programState", "robotmode", "safetystatus", "running"), 2.0, port)
        assert answers == {
            "programState": "STOPPED <unnamed>", "robotmode": "Robotmode: RUNNING",
            "safetystatus": "Safetystatus: NORMAL", "running": "Program running: false",
        }  # fmt: skip
        emulator.runtime_state, emulator.programs = 2, ["rtde_control"]  # ur_rtde's script running
        assert ask_dashboard("127.0.0.1", ("programState",), 2.0, port)["programState"] == "PLAYING rtde_control"
        emulator.protective_stop()
        answers = ask_dashboard("127.0.0.1", ("programState", "safetystatus"), 2.0, port)
        assert answers == {"programState": "PAUSED rtde_control", "safetystatus": "Safetystatus: PROTECTIVE_STOP"}
        confirmed, said = confirm_rest_by_dashboard(lambda r: ask_dashboard("127.0.0.1", r, 2.0, port), 2.0, 0.0)
        assert confirmed and said.startswith("dashboard: programState PAUSED rtde_control, robotmode RUNNING")
