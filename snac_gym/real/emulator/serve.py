"""``snac-gym emulate-ur``: an emulated controller in the foreground, with faults from flags."""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from typing import Any

from snac_gym.common._signals import STOP_SIGNALS
from snac_gym.real.emulator.controller import UREmulator


def parse_numbers(text: str, name: str, counts: tuple[int, ...]) -> list[float]:
    """Comma-separated numbers of ``text``, as many as one of ``counts``.

    Raises:
        ValueError: With ``name`` in the message, on a bad value or count.
    """
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from exc
    if len(values) not in counts:
        raise ValueError(f"{name} needs {' or '.join(map(str, counts))} numbers, got {len(values)} in {text!r}")
    return values


def fault_plan(
    protective_stop_at: float | None = None,
    emergency_stop_at: float | None = None,
    latency_spike: str | None = None,
    drop_at: float | None = None,
    stale_at: float | None = None,
    watchdog_expiry_at: float | None = None,
    drop_for: float | None = None,
    nonfinite_at: float | None = None,
) -> list[tuple[float, str, tuple[Any, ...]]]:
    """The faults to schedule, ``(seconds after the first speedJ, method, args)``.

    ``drop_for``: with ``drop_at``, the link comes back (new connections accepted) that many
    seconds after the drop; without it the link stays down.

    Raises:
        ValueError: On a malformed ``latency_spike`` (``AT,LENGTH`` in seconds), or ``drop_for``
            without ``drop_at``.
    """
    plan: list[tuple[float, str, tuple[Any, ...]]] = []
    options = {
        "--protective-stop-at": protective_stop_at, "--emergency-stop-at": emergency_stop_at, "--drop-at": drop_at,
        "--stale-at": stale_at, "--watchdog-expiry-at": watchdog_expiry_at, "--drop-for": drop_for,
        "--nonfinite-at": nonfinite_at,
    }  # fmt: skip
    for option, seconds in options.items():  # here, so that the message names the option
        if seconds is not None and not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"{option} must be a non-negative number of seconds, got {seconds!r}")
    singles = {
        "protective_stop": protective_stop_at, "emergency_stop": emergency_stop_at, "drop_connection": drop_at,
        "stale_data": stale_at, "expire_watchdog": watchdog_expiry_at, "nonfinite_state": nonfinite_at,
    }  # fmt: skip
    plan += [(at, fault, ()) for fault, at in singles.items() if at is not None and fault != "drop_connection"]
    if drop_for is not None and drop_at is None:
        raise ValueError("--drop-for needs --drop-at (when the link drops)")
    if drop_at is not None:
        plan.append((drop_at, "drop_connection", () if drop_for is None else (drop_for,)))
    if latency_spike is not None:
        at, length = parse_numbers(latency_spike, "--latency-spike (AT,SECONDS)", (2,))
        if not all(math.isfinite(v) and v >= 0 for v in (at, length)):
            raise ValueError(
                f"--latency-spike (AT,SECONDS) must be two non-negative numbers of seconds, got {latency_spike!r}"
            )
        plan.append((at, "latency_spike", (length,)))
    return plan


def serve(emulator: UREmulator, duration: float | None, echo: Callable[[str], None]) -> int | None:
    """Run ``emulator`` until ``duration`` s have passed, a stop signal or a failed thread; then close it.

    Returns:
        The number of the signal that stopped it (SIGINT, SIGTERM, SIGHUP or SIGQUIT), else ``None``.
    """
    stop = threading.Event()
    received: list[int] = []

    def handler(signum: int, frame: object) -> None:
        received.append(signum)
        stop.set()

    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    logging.basicConfig(level=logging.INFO, format="%(asctime)s emulate-ur %(levelname)s: %(message)s")
    try:
        with emulator:
            ports = ", ".join(f"{name} {port}" for name, port in emulator.ports.items())
            echo(f"emulated UR controller ({emulator.series}, {emulator.frequency:g} Hz) on {emulator.host}: {ports}")
            deadline = None if duration is None else time.monotonic() + duration
            while not stop.wait(0.2):
                if emulator.failure is not None or (deadline is not None and time.monotonic() >= deadline):
                    break
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)
    return received[0] if received else None
