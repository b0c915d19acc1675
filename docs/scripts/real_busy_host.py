"""`snac-gym real` against the emulated UR controller with the host's cores kept busy: the 125 Hz loop with and
without `--rt-priority`. Prints one markdown row per run (docs/real-arm.md, "A loop on a busy host").

    python docs/scripts/real_busy_host.py --runs 2 --hogs 2

Each run: the emulator on 127.0.0.1 (standard ports), `--hogs` processes spinning at normal priority (one per
core saturates the host), then the default 15 s reach (1875 periods) of `snac-gym real`; the figures come
from its `reach_snac_real.json` and its exit code.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from snac_gym.real.emulator.process import EmulatorProcess

HOG = "while True: pass"


def run(rt_priority: int, hogs: int, out: Path) -> str:
    command = [
        sys.executable,
        "-m",
        "snac_gym.apps.cli",
        "real",
        "--host",
        "127.0.0.1",
        "--task",
        "reach",
        "--controller",
        "snac",
        "--no-plots",
        "--out",
        str(out),
    ]
    if rt_priority:
        command += ["--rt-priority", str(rt_priority)]
    spinners = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(hogs)]
    try:
        with EmulatorProcess(series="cb", host="127.0.0.1", bind_timeout=90.0):
            load = os.getloadavg()[0]
            done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    finally:
        for spinner in spinners:
            spinner.kill()
    info = json.loads((out / "reach_snac_real.json").read_text())
    timing, stop = info.get("timing", {}), info.get("stop_reason")
    rows = (out / "reach_snac_timing.csv").read_text().splitlines()[1:]
    periods = len(rows)
    values = [float(row.split(",")[1]) for row in rows]
    longest = max(range(periods), key=values.__getitem__) if periods else -1
    ended = "ran to its end" if done.returncode == 0 else f"exit {done.returncode}: {stop or done.stderr.strip()[:80]}"
    return (
        f"| {rt_priority or 'off'} | {hogs} | {load:.2f} | {timing.get('period_ms_p50', float('nan')):.3f} | "
        f"{timing.get('period_ms_p99', float('nan')):.3f} | {timing.get('period_ms_max', float('nan')):.3f} "
        f"(step {longest}) | "
        f"{timing.get('late_periods', '?')} | {periods} | {ended} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="runs of each setting, alternating")
    parser.add_argument("--hogs", type=int, default=os.cpu_count() or 2, help="busy processes beside the loop")
    parser.add_argument("--rt-priority", type=int, default=20)
    args = parser.parse_args()
    print(
        "| --rt-priority | busy processes | load average | p50 ms | p99 ms | max ms (at step) | late periods "
        "| periods | end |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for k in range(args.runs):
        for priority in (0, args.rt_priority):
            with tempfile.TemporaryDirectory() as folder:
                print(run(priority, args.hogs, Path(folder) / "out"), flush=True)


if __name__ == "__main__":
    main()
