"""How fast an interrupted ``snac-gym evaluate`` ends: send SIGINT or SIGTERM at given times, report exit code and
delay.

    python docs/scripts/interrupt_timing.py --at 7 9 11 21.5

Runs ``snac-gym evaluate --samples 20 --chunk-size 2 --workers 2 --controllers snac,dls,svf,rnn,lqr,optimal``
(about 23 s uninterrupted on a 2-core machine: effort matching from about 2.5 s, the optimum from about 21 s)
once per signal and time, in a fresh folder each.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ARGS = [
    "--samples",
    "20",
    "--chunk-size",
    "2",
    "--workers",
    "2",
    "--controllers",
    "snac,dls,svf,rnn,lqr,optimal",
    "--no-progress",
    "--effort-samples",
    "0",
]


def interrupt(out: Path, signum: int, at: float, bound: float = 30.0) -> tuple[int | None, float | None, str]:
    """Exit code, seconds from the signal to the exit (``None``: still running after ``bound`` s), last stderr line."""
    process = subprocess.Popen(
        [sys.executable, "-m", "snac_gym.apps.cli", "evaluate", "--out", str(out), *ARGS],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # A background job of a non-interactive shell inherits SIGINT ignored; a terminal's Ctrl-C does not.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    time.sleep(at)
    process.send_signal(signum)
    sent = time.perf_counter()
    try:
        _, err = process.communicate(timeout=bound)
    except subprocess.TimeoutExpired:
        process.kill()
        return None, None, "still running"
    return process.returncode, time.perf_counter() - sent, (err.strip().splitlines() or [""])[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--at", type=float, nargs="+", default=[7.0, 9.0, 11.0])
    parser.add_argument("--signals", nargs="+", default=["SIGINT", "SIGTERM"])
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        for name in options.signals:
            for at in options.at:
                code, delay, line = interrupt(Path(folder) / f"{name}-{at}", int(getattr(signal, name)), at)
                took = "HUNG" if delay is None else f"{delay:.2f} s"
                print(f"{name:8s} at {at:5.1f} s: exit {code}, {took} after the signal: {line}")


if __name__ == "__main__":
    main()
