"""The ur_rtde client in its own process, and the small protocol the parent drives it with.

ur_rtde can block while holding the GIL (``speedStop`` on a link that just dropped retries its
reconnect), reconnect by itself from its background threads, and crash the interpreter (a
segfault in its reconnect after a controller stall). None of that may take a real run down or
keep it from stopping and writing its log, so the client lives here, in a child process
(:func:`serve`) that the parent
(:class:`~snac_gym.real.connections.URRTDEConnection`) can always see fail and kill.

Protocol: frames of a 4-byte big-endian length and a pickle, over the child's stdin (requests
``(seq, name, args)``) and the file descriptor that was its stdout (replies ``(seq, status,
payload)``, status ``"ok"``, ``"lost"`` (the link is down) or ``"error"``). ur_rtde prints to
the C streams; the child sends both to its stderr, which the parent reads line by line: a line
about reconnecting makes the parent kill the child, so that only the project reconnects.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import pickle
import signal
import struct
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from snac_gym.common.errors import LinkDown

#: Frame header: the length of the pickle that follows.
HEADER = struct.Struct(">I")
#: A line of ur_rtde's output that says it is reconnecting by itself (lower-cased match).
RECONNECT_MARKERS = ("reconnect",)
NORMAL, PROTECTIVE_STOP, EMERGENCY_STOP = "normal", "protective_stop", "emergency_stop"
#: Seconds without a new package, while waiting for rest after ``speedStop``, after which the state counts as
#: stale (12 periods at 125 Hz, 50 at 500 Hz: beyond the stale rule's 3, margin for a busy host).
STALE_WHILE_STOPPING_S = 0.1


def write_frame(fd: int, message: Any) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    os.write(fd, HEADER.pack(len(data)) + data)


def read_frame(stream: BinaryIO) -> Any:
    """The next frame of ``stream``; ``None`` at end of file."""
    header = stream.read(HEADER.size)
    if len(header) < HEADER.size:
        return None
    (size,) = HEADER.unpack(header)
    body = stream.read(size)
    return None if len(body) < size else pickle.loads(body)


class Client:
    """What the child does with ur_rtde: one method per request of the parent."""

    def __init__(self) -> None:
        self.control: Any = None
        self.receive: Any = None
        self.streaming = False
        self.dashboard: Any = None
        self.dt = 0.008

    def connect(self, host: str, frequency: float, control: bool) -> dict[str, Any]:
        # the real extra (ur_rtde)
        import rtde_control
        import rtde_receive

        self.dt = 1.0 / frequency
        self.receive = rtde_receive.RTDEReceiveInterface(host, frequency)
        if control:
            self.control = rtde_control.RTDEControlInterface(host, frequency)
        return self.state()

    def link_up(self) -> bool:
        receive_up = self.receive is not None and self.receive.isConnected()
        return receive_up and (self.control is None or self.control.isConnected())

    def _require_link(self) -> None:
        if not self.link_up():
            raise LinkDown("was lost")

    def state(self) -> dict[str, Any]:
        """q, θ̇, TCP pose, speed scaling and timestamp of one RTDE package, with the safety state.

        ur_rtde's getters each read the latest package, which may change between two calls; the
        reads are repeated until the timestamp is the same before and after.
        """
        self._require_link()
        receive = self.receive
        for _ in range(5):
            stamp = float(receive.getTimestamp())
            q, qd = receive.getActualQ(), receive.getActualQd()
            tcp, scaling = receive.getActualTCPPose(), float(receive.getSpeedScaling())
            if float(receive.getTimestamp()) == stamp:
                break
        safety = NORMAL
        if receive.isEmergencyStopped():
            safety = EMERGENCY_STOP
        elif receive.isProtectiveStopped():
            safety = PROTECTIVE_STOP
        return {"q": q, "qd": qd, "tcp": tcp, "scaling": scaling, "stamp": stamp, "safety": safety}

    def _ensure_program(self, timeout: float) -> None:
        """Re-upload ur_rtde's control script if the watchdog ended it while the host was idle."""
        if self.control.isProgramRunning():
            return
        self.control.reuploadScript()
        deadline = time.perf_counter() + timeout
        while not self.control.isProgramRunning():
            if time.perf_counter() > deadline:
                raise LinkDown("did not start the control script (is the arm in remote control?)")
            time.sleep(self.dt)

    def command(
        self, velocities: list[float], acceleration: float, watchdog_frequency: float, program_timeout: float
    ) -> bool:
        self._require_link()
        if not self.streaming:  # the first command after a stop: arm the watchdog for this stream
            with _helpers_above():
                # Said before each handshake, so that if one blocks, the parent's report names it.
                _say("stream start: isProgramRunning/reuploadScript")
                self._ensure_program(program_timeout)
                _say("stream start: setWatchdog")
                self.control.setWatchdog(watchdog_frequency)
                _say("stream start: first speedJ")
                self.streaming = True
                return bool(self.control.speedJ(velocities, acceleration, self.dt))
        # No kickWatchdog: ur_rtde 1.6.5 sends it as input_int_register_0 = 0, which overwrites
        # speedJ's command id before the control script reads it when both land in the same
        # controller cycle; speedJ's own package refreshes the watched register every period.
        return bool(self.control.speedJ(velocities, acceleration, self.dt))

    def stop(self, deceleration: float, rest_timeout: float) -> str:
        """``speedStop``, then wait for rest; never on a link seen down (ur_rtde would reconnect).

        Rest counts only from a package newer than the one before ``speedStop``: a frozen state
        (the controller's timestamp not advancing for :data:`STALE_WHILE_STOPPING_S`) cannot
        show rest, and is said at once (``stale state: …``), so that the parent stops the script and
        asks another source than RTDE.
        """
        self.streaming = False
        if self.control is None:
            return "nothing sent"
        if not self.link_up():
            return "link down: left to the controller's watchdog"
        try:
            before = float(self.receive.getTimestamp())
            with _helpers_above():
                self.control.speedStop(deceleration)
        except RuntimeError:
            return "disconnected: left to the controller's watchdog"
        deadline = time.perf_counter() + rest_timeout
        stamp, since = before, time.perf_counter()
        while time.perf_counter() < deadline:
            try:
                now_stamp = float(self.receive.getTimestamp())
                speed = max(map(abs, self.receive.getActualQd()))
            except RuntimeError:
                return "disconnected while stopping"
            if now_stamp != stamp:
                stamp, since = now_stamp, time.perf_counter()
            elif time.perf_counter() - since > STALE_WHILE_STOPPING_S:
                return (
                    f"stale state: the controller's timestamp stayed at {stamp:.6f} s for "
                    f"{(time.perf_counter() - since) * 1e3:.0f} ms after speedStop, rest cannot be read from RTDE"
                )
            if stamp > before and speed < 1e-3:
                return "at rest"
            time.sleep(self.dt)
        return f"still moving after {rest_timeout:g} s"

    def stop_script(self) -> str:
        """``stopScript``: the control script ends, and with it anything that could drive the arm."""
        self.streaming = False
        if self.control is None:
            return "nothing sent"
        if not self.link_up():
            return "link down: not sent"
        with _helpers_above():
            self.control.stopScript()
        return "control script stopped"

    def move_to(self, q: list[float], speed: float, program_timeout: float) -> bool:
        self._require_link()
        with _helpers_above():
            self._ensure_program(program_timeout)
            return bool(self.control.moveJ(q, speed, 0.5))

    def unlock_protective_stop(self, host: str) -> tuple[bool, str]:
        """The dashboard's ``unlock protective stop``: ``(released, the controller's answer)``.

        ur_rtde raises when the controller refuses (within its 5 s lockout); that is an answer,
        not a failure of the client.
        """
        import dashboard_client  # the real extra (ur_rtde)

        if self.dashboard is None or not self.dashboard.isConnected():
            self.dashboard = dashboard_client.DashboardClient(host)
            self.dashboard.connect()
        try:
            self.dashboard.unlockProtectiveStop()
        except RuntimeError as exc:
            return False, str(exc).splitlines()[0] if str(exc) else "refused"
        return True, "Protective stop releasing"

    def close(self) -> str:
        """End the control script; the process then exits, which closes the sockets.

        ``disconnect`` would take 0.5 s per interface (ur_rtde joins its threads): leaving the
        process does the same for the controller at once.
        """
        if self.control is not None and self.link_up():
            with _helpers_above():
                self.control.stopScript()
            return "control script stopped"
        return "nothing to stop"


@contextlib.contextmanager
def _helpers_above() -> Iterator[None]:
    """Under ``SCHED_FIFO`` (inherited from a real-time loop): ur_rtde's own threads one priority above this one.

    ur_rtde's handshakes (the script's upload, the first ``speedJ`` of a stream, ``speedStop``,
    ``stopScript``) wait for the controller by spinning on what its receive threads read; at
    the same FIFO priority a spinning thread is never preempted, so a receive thread on its CPU
    could not run until the call's deadline killed the client (seen at a stream's first
    ``speedJ`` and at ``stopScript`` on this 2-core machine: 3 of 7 runs at 500 Hz). The
    period's own calls keep equal priorities: raised for them too, the receive threads' wake-ups
    pushed the loop's p99 from 2.02 to 2.6 ms (docs/hardware-in-the-loop.md).
    """
    if os.sched_getscheduler(0) != os.SCHED_FIFO:
        yield
        return
    main = threading.get_native_id()
    own = os.sched_getparam(0).sched_priority
    above = min(own + 1, os.sched_get_priority_max(os.SCHED_FIFO))
    helpers = [int(tid) for tid in os.listdir("/proc/self/task") if int(tid) != main]
    _set_fifo(helpers, above)
    try:
        yield
    finally:
        _set_fifo(helpers, own)


def _set_fifo(threads: list[int], priority: int) -> None:
    for tid in threads:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except OSError:  # gone meanwhile, or not permitted: left as it was
            pass


def _say(text: str) -> None:
    """A line for the parent's record of the client's output (``client_output`` in ``real.json``)."""
    print(f"client: {text}", file=sys.stderr, flush=True)


def _die_with_parent() -> None:
    """Linux: SIGKILL this process when its parent dies (the controller's watchdog then stops the arm)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass


def _answer(client: Client, name: str, args: tuple[Any, ...]) -> tuple[str, Any]:
    try:
        return "ok", getattr(client, name)(*args)
    except LinkDown as exc:
        return "lost", str(exc)
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which decides
        text = str(exc).splitlines()[0] if str(exc) else ""
        error = f"{type(exc).__name__}: {text}".rstrip(": ")
        # A request that fails with the link down failed because it went (ur_rtde may raise from its own reconnect,
        # "Timeout connecting to UR dashboard server", before it says it reconnects): a lost link, in ur_rtde's words.
        return ("lost", f"was lost ({error})") if _link_down(client) else ("error", error)


def _link_down(client: Client) -> bool:
    """Whether ur_rtde says the link is down (not when it cannot say: a client in a state it cannot report)."""
    try:
        return client.receive is not None and not client.link_up()
    except Exception:  # noqa: BLE001 - the question failed too: the caller reports the first error as it is
        return False


def serve() -> None:
    """Child side: answer requests until end of input, a ``close`` request, or a kill."""
    _die_with_parent()
    # Terminal signals go to the parent, which stops the arm through this process.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    replies = os.dup(1)
    os.dup2(2, 1)  # ur_rtde's std::cout joins its std::cerr, which the parent watches
    sys.stdout = sys.stderr
    requests = sys.stdin.buffer
    client = Client()
    names = {"connect", "state", "command", "stop", "stop_script", "move_to", "unlock_protective_stop", "close"}
    while True:
        message = read_frame(requests)
        if message is None:
            break
        seq, name, args = message
        reply = _answer(client, name, args) if name in names else ("error", f"no request {name!r}")
        write_frame(replies, (seq, *reply))
        if name == "close":
            break
    os._exit(0)  # no C++ destructors: they join ur_rtde's threads, which may be stuck on a dead link


def as_arrays(state: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, str]:
    """The parent's view of a ``state`` reply."""
    return (
        np.array(state["q"], dtype=float),
        np.array(state["qd"], dtype=float),
        np.array(state["tcp"], dtype=float),
        float(state["scaling"]),
        float(state["stamp"]),
        str(state["safety"]),
    )
