"""The emulated controller's listening sockets and threads: its life cycle, the link's cuts and returns.

A layer of :class:`~snac_gym.real.emulator.controller.UREmulator` (see :mod:`~snac_gym.real.emulator.state`):
the ports bound (waiting for busy standard ports), one thread per connection, the threads at real-time
priority, and the link restored after :meth:`~snac_gym.real.emulator.faults.Faults.drop_connection`.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from typing import Any

from typing_extensions import Self

from snac_gym.real.emulator.servers import RTDEConnection, serve_dashboard, serve_script
from snac_gym.real.emulator.state import PORT_OFFSETS, ControllerState, log

__all__ = ["Listeners", "close_quietly"]


class Listeners(ControllerState):
    """The servers' sockets and the emulator's threads, started and closed."""

    # ----------------------------------------------------------------- life cycle
    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> Self:
        """Bind the servers (waiting for busy standard ports) and start the control cycle.

        Raises:
            OSError: If the ports stay busy for ``bind_timeout`` s.
        """
        deadline = time.monotonic() + self.bind_timeout
        while True:
            try:
                self._bind_all()
                break
            except OSError as exc:
                if time.monotonic() >= deadline:
                    raise OSError(
                        f"cannot listen on {self.host} port {exc.filename}: {exc.strerror} "
                        "(another emulator or UR software running?)"
                    ) from exc
                time.sleep(0.2)
        for name, listener in zip(PORT_OFFSETS, self._listeners):
            self._spawn(self._accept_loop, listener, name)
        self._spawn(self._control_loop)
        self.event(f"listening on {self.host}: " + ", ".join(f"{k} {v}" for k, v in self.ports.items()))
        return self

    def _bind_all(self) -> None:
        listeners = []
        try:
            for name, offset in PORT_OFFSETS.items():
                port = self.ports.get(name, 0 if self.port_base == 0 else self.port_base + offset)
                sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                listeners.append(sock)
                try:
                    sock.bind((self.host, port))
                except OSError as exc:
                    exc.filename = str(port)
                    raise
                sock.listen(8)
                sock.settimeout(0.1)
                self.ports[name] = sock.getsockname()[1]
        except OSError:
            for sock in listeners:
                sock.close()
            raise
        self._listeners = listeners

    def _spawn(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(
            target=self._at_priority, args=(target, *args), daemon=True, name=f"emulate-ur-{target.__name__}"
        )
        thread.start()
        self._threads.append(thread)

    def _at_priority(self, target: Any, *args: Any) -> None:
        """Run ``target`` under ``SCHED_FIFO`` at ``rt_priority`` (when set), every thread alike.

        The servers' threads need the interpreter lock that the control cycle needs: at normal
        priority on a busy host, one descheduled while holding it stalled the cycle (at 500 Hz,
        no package for 6 ms and more; a command read after the 10 ms watchdog had expired).
        """
        if self.rt_priority and target != self._control_loop:  # the cycle says so itself if not permitted
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            except (PermissionError, OSError, AttributeError):
                pass
        try:
            target(*args)
        except BaseException as exc:  # a dead thread would leave a controller that looks alive: stop it all
            self.failure = exc
            log.exception(
                "emulate-ur: %s ended by %s: %s; the emulator stops", target.__name__, type(exc).__name__, exc
            )
            self._stop.set()

    def close(self) -> None:
        """Stop the control cycle, close every connection and listener, and join the threads."""
        self._stop.set()
        with self.lock:
            for conn in list(self._connections):
                conn.close()
            for sock in self._sockets:
                close_quietly(sock)
        for sock in self._listeners:
            close_quietly(sock)
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._threads = [t for t in self._threads if t.is_alive()]

    def _accept_loop(self, listener: socket.socket, name: str) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._serve(sock, name)

    def _serve(self, sock: socket.socket, name: str) -> None:
        with self.lock:
            if name == "rtde":
                conn = RTDEConnection(self, sock)
                self._connections.append(conn)
                self._spawn(conn.serve)
                return
            self._sockets.append(sock)
        if name == "dashboard":
            self._spawn(serve_dashboard, self, sock)
        else:
            self._spawn(serve_script, self, sock)

    def _restore_link(self) -> None:
        try:
            self._bind_all()
        except OSError as exc:  # taken meanwhile: retried next cycle
            self.event(f"link not restored yet: {exc}")
            return
        self._awaiting_fresh_state = True  # first: a client that sees the link back must find it set
        self._link_down = False
        for name, listener in zip(PORT_OFFSETS, self._listeners):
            self._spawn(self._accept_loop, listener, name)
        self.event("link restored")

    def _control_loop(self) -> None:
        """The control cycle's thread: :class:`~snac_gym.real.emulator.controller.UREmulator` runs it."""
        raise NotImplementedError


def close_quietly(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    sock.close()
