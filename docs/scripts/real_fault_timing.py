"""How `snac-gym real` ends under each controller fault, measured command against command.

For each case it starts ``snac-gym emulate-ur`` with the fault flags, then
``snac-gym real --host 127.0.0.1 --task reach --controller snac --out OUT``, and reports the exit
code, the one line, the seconds from the fault (the emulator's log line) to the exit, the rows of
the log written, and the loop timing. With ``--loop`` it runs the fault-free 15 s reach instead
and prints the loop period figures (p50, p99, max, late periods).

    .venv/bin/python docs/scripts/real_fault_timing.py            # the three faults
    .venv/bin/python docs/scripts/real_fault_timing.py --loop 3   # three fault-free runs
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import pandas as pd

CASES = {
    "3 s stall": ["--latency-spike", "1,3"],
    "30 s stall": ["--latency-spike", "1,30"],
    "0.2 s stall, then dropped link": ["--latency-spike", "1,0.2", "--drop-at", "1.1"],
}
FAULT_EVENTS = ("latency spike", "connections dropped")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "snac_gym.apps.cli", *args]


def _fault_time(log: Path) -> float | None:
    """Wall-clock time of the emulator's first fault line (``2026-11-24 19:25:46,242 emulate-ur: …``)."""
    for line in log.read_text().splitlines():
        if any(event in line for event in FAULT_EVENTS):
            return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
    return None


def run_case(flags: list[str], out: Path) -> dict:
    emulator_log = out.with_suffix(".emulator.log")
    with emulator_log.open("w") as sink:
        emulator = subprocess.Popen(_cli("emulate-ur", "--rt-priority", "20", "--duration", "90", *flags),
                                    stdout=sink, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        time.sleep(2.0)
        real = subprocess.run(_cli("real", "--host", "127.0.0.1", "--task", "reach", "--controller", "snac",
                                   "--out", str(out)), capture_output=True, text=True, timeout=120)  # fmt: skip
        exited = time.time()
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)
    fault = _fault_time(emulator_log)
    summary = json.loads(next(out.glob("*_real.json")).read_text())
    log = next(out.glob("*_log.parquet"), None)
    periods = pd.read_csv(next(out.glob("*_timing.csv")))["period_ms"]
    return {
        "max after the first period (ms)": round(float(periods.iloc[1:].max()), 3) if len(periods) > 1 else None,
        "exit code": real.returncode,
        "line": (real.stderr or real.stdout).strip().splitlines()[-1],
        "fault to exit (s)": None if fault is None else round(exited - fault, 2),
        "rows logged": None if log is None else len(pd.read_parquet(log)),
        "ended": summary.get("ended", "completed"),
        "timing": {k: round(v, 3) for k, v in summary["timing"].items()},
    }


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        if len(sys.argv) > 1 and sys.argv[1] == "--loop":
            for k in range(int(sys.argv[2]) if len(sys.argv) > 2 else 1):
                result = run_case([], Path(tmp) / f"loop{k}")
                timing = result["timing"]
                figures = {
                    key: timing[key] for key in ("period_ms_p50", "period_ms_p99", "period_ms_max", "late_periods")
                }
                figures["max after the first period"] = result["max after the first period (ms)"]
                print(f"run {k}: load {os.getloadavg()[0]:.2f}", figures)
            return
        for name, flags in CASES.items():
            print(name, json.dumps(run_case(flags, Path(tmp) / name.replace(" ", "_").replace(",", "")), indent=1))


if __name__ == "__main__":
    main()
