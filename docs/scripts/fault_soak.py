"""A fault soak: N short `snac-gym real` episodes through the real ur_rtde client, each against its own
`snac-gym emulate-ur` with one seeded random fault, tabulated by how each run ended and how its arm was
confirmed at rest (docs/real-arm.md, "A fault soak").

Each episode (seeded by ``--seed`` and its number):

* a UR model drawn from every one ``snac-gym real`` drives, a start pose and a reach target from that arm's
  own sampler (the emulator starts the arm at that pose, so there is no long ``moveJ``);
* one fault drawn from every kind ``emulate-ur`` injects (:data:`KINDS`; ``none`` for a fault-free
  control), at a random time within the episode;
* ``snac-gym emulate-ur --host 127.0.3.K …`` on this worker's own loopback address (ur_rtde's ports are
  fixed: an address per emulator is what a free port is for other clients), then ``snac-gym real --host
  127.0.3.K --steps 375`` (3 s at 125 Hz) against it.

Every arm streams at 125 Hz (``--series cb``; an e-Series arm may), as the test suite runs them: on a
shared 2-core host the e-Series' 500 Hz misses deadlines without real-time priority (``--own-series``
runs each at its own rate).

    .venv/bin/python docs/scripts/fault_soak.py --episodes 200 --jobs 2 --seed 0 --out /tmp/soak

Prints the tables (markdown) and writes ``episodes.csv`` to ``--out``. Exit 1 if any run ended neither at
confirmed rest nor with its stated reason.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import queue
import random
import re
import subprocess
import sys
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from snac_gym.evaluation.samples import generate_samples

from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS
from snac_gym.sampling import SampleSpace

#: The faults ``snac-gym emulate-ur`` injects, and ``none`` (a fault-free control run).
KINDS = (
    "none", "stale", "drop", "drop and return", "stall", "protective stop", "emergency stop", "watchdog expiry",
    "non-finite state", "speed slider", "wrong tool",
)  # fmt: skip
STEPS = 375  # 3 s at 125 Hz
ROBOTS = tuple(UR_MODELS)


def fault_flags(kind: str, rng: random.Random) -> list[str]:
    """``emulate-ur``'s flags for one fault of ``kind``, at a random time (s after the first speedJ)."""
    at = f"{rng.uniform(0.3, 2.5):.2f}"
    return {
        "none": [],
        "stale": ["--stale-at", at],
        "drop": ["--drop-at", at],
        "drop and return": ["--drop-at", at, "--drop-for", f"{rng.uniform(0.2, 1.5):.2f}"],
        "stall": ["--latency-spike", f"{at},{rng.uniform(0.02, 3.0):.2f}"],
        "protective stop": ["--protective-stop-at", at],
        "emergency stop": ["--emergency-stop-at", at],
        "watchdog expiry": ["--watchdog-expiry-at", at],
        "non-finite state": ["--nonfinite-at", at],
        "speed slider": ["--speed-scaling", f"{rng.uniform(0.1, 0.9):.2f}"],
        "wrong tool": ["--tcp-offset", ",".join(f"{rng.uniform(-0.03, 0.03):.4f}" for _ in range(3))],
    }[kind]


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "snac_gym.apps.cli", *args]


#: The episodes' processes read and write byte code in a folder of their own (``--out``/pycache): on a checkout
#: others edit meanwhile, a shared ``__pycache__`` once gave ``EOFError: marshal data too short`` at import.
ENV = dict(os.environ)


def run_episode(episode: int, seed: int, host: str, out: Path, own_series: bool, tries: int = 3) -> dict:
    """One episode; started again (at most ``tries`` times, same draw) when a process died before it began:
    a Python traceback at import, or an emulator that never listened (``retries`` counts them)."""
    for attempt in range(tries):
        row = _episode(episode, seed, host, out, own_series)
        if row["started"]:
            break
    row["retries"] = attempt
    return row


def _numbers(values: np.ndarray) -> str:
    return ",".join(f"{v:.6f}" for v in values)


def _episode(episode: int, seed: int, host: str, out: Path, own_series: bool) -> dict:
    rng = random.Random(seed * 100_003 + episode)
    robot, kind = rng.choice(ROBOTS), rng.choice(KINDS)
    flags = fault_flags(kind, rng)
    kinematics = Kinematics(robot)
    (sample,) = generate_samples(kinematics, SampleSpace.for_robot(kinematics), rng.randrange(2**31), "reach", range(1))
    series = [] if own_series else ["--series", "cb"]
    folder = out / f"episode_{episode:04d}"
    folder.mkdir(parents=True, exist_ok=True)
    emulator_log = folder / "emulator.log"
    with emulator_log.open("w") as sink:
        emulator = subprocess.Popen(
            _cli("emulate-ur", "--host", host, "--robot", robot, *series, "--q0", _numbers(sample.q0),
                 "--duration", "120", *flags), stdout=sink, stderr=subprocess.STDOUT, env=ENV,
        )  # fmt: skip
    row = {"episode": episode, "robot": robot, "fault": kind, "flags": " ".join(flags)}
    try:
        deadline = time.monotonic() + 60.0
        while "listening on" not in emulator_log.read_text() and time.monotonic() < deadline:
            if emulator.poll() is not None:
                break
            time.sleep(0.05)
        started = time.monotonic()
        try:
            real = subprocess.run(
                _cli("real", "--host", host, "--robot", robot, *series, "--controller", "lqr", "--steps", str(STEPS),
                     "--q0", _numbers(sample.q0), "--target", _numbers(sample.reference.target), "--no-plots",
                     "--out", str(folder / "run")),
                capture_output=True, text=True, timeout=120, env=ENV,
            )  # fmt: skip
            code, output = real.returncode, (real.stdout + real.stderr).strip()
        except subprocess.TimeoutExpired as exc:
            code, output = "timeout", f"did not end within 120 s: {exc}"
        row["wall_s"] = round(time.monotonic() - started, 2)
    finally:
        emulator.terminate()
        try:
            emulator.wait(timeout=15)
        except subprocess.TimeoutExpired:
            emulator.kill()
            emulator.wait()
    summary_file = next((folder / "run").glob("*_real.json"), None)
    summary = json.loads(summary_file.read_text()) if summary_file else {}
    by = summary.get("rest_confirmed_by") or ""
    row.update(
        exit_code=code,
        ending=classify(code, summary, output),
        rest_confirmed=summary.get("rest_confirmed"),
        rest_source=by.split(":", 1)[0] if by else "",
        rest_confirmed_by=by,
        rest_confirmed_after_s=summary.get("rest_confirmed_after_s"),
        rest_not_confirmed=summary.get("rest_not_confirmed") or "",
        stopped_by=summary.get("stopped_by") or "",
        last_stop=summary.get("last_stop") or "",
        fault_fired=any(word in emulator_log.read_text() for word in _FAULT_LINES.get(kind, ("",))),
        line=output.splitlines()[-1] if output else "",
    )
    row["accounted"] = accounted(row, summary)
    # `snac-gym real` prints one line and never a traceback: one means Python died before the command ran.
    row["started"] = "listening on" in emulator_log.read_text() and "Traceback (most recent call last)" not in output
    return row


#: The emulator's log line that says the fault was injected (a fault timed after the run's end never is).
_FAULT_LINES = {
    "stale": ("stale data on",), "drop": ("connections dropped",), "drop and return": ("connections dropped",),
    "stall": ("latency spike",), "protective stop": ("protective stop",), "emergency stop": ("emergency stop",),
    "watchdog expiry": ("watchdog expiry injected",), "non-finite state": ("non-finite state on",),
}  # fmt: skip


def classify(code: object, summary: dict, output: str) -> str:
    """A short name for how the run ended: its stop reason's rule, or the error's kind."""
    reason = summary.get("stop_reason") or ""
    if code == 0:
        return "ran to its end"
    if code == 1:
        text = summary.get("client_failure") or output
        if "reconnect" in text:
            return "link lost (ur_rtde began to reconnect)"
        if "did not return from" in text:
            return "link lost (client missed its deadline)"
        return "link lost"
    if code == 2:
        line = output.splitlines()[-1] if output else ""
        return "refused: " + ("TCP mismatch" if "TCP mismatch" in line else line.removeprefix("error: ")[:60])
    for rule in ("stale joint state", "non-finite", "TCP mismatch", "control loop stalled", "control loop missed",
                 "controller reports protective_stop", "controller reports emergency_stop", "left the task box",
                 "of its limit", "rejected speedJ"):  # fmt: skip
        if rule in reason:
            return rule
    return (reason or output.splitlines()[-1] if output else str(code))[:60]


def accounted(row: dict, summary: dict) -> bool:
    """Whether the run ended at confirmed rest or with its stated reason: the record says rest was confirmed,
    or says why not; or nothing ever moved (a start refused before the stream)."""
    if row["rest_confirmed"] is True:
        return True
    if row["rest_confirmed"] is False and row["rest_not_confirmed"]:
        return True
    return row["exit_code"] == 2 and summary.get("steps_logged", 0) == 0


def _quantiles(values: list[float]) -> str:
    if not values:
        return "– | – | – | –"
    p50, p90, p99 = np.percentile(values, [50, 90, 99])
    return f"{p50:.3f} | {p90:.3f} | {p99:.3f} | {max(values):.3f}"


def tables(rows: list[dict]) -> str:
    lines = ["| fault | runs | exit code: ending (runs) |", "|---|---|---|"]
    by_kind: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        by_kind[row["fault"]].append(row)
    for kind in KINDS:
        runs = by_kind.get(kind, [])
        if not runs:
            continue
        counts = Counter((str(r["exit_code"]), r["ending"]) for r in runs)
        cells = "; ".join(f"{c}: {e} ({n})" for (c, e), n in sorted(counts.items()))
        lines.append(f"| {kind} | {len(runs)} | {cells} |")
    codes = Counter(str(r["exit_code"]) for r in rows)
    lines.append(f"| all | {len(rows)} | " + ", ".join(f"exit {c}: {n}" for c, n in sorted(codes.items())) + " |")
    lines += ["", "| fault | confirmed by RTDE | confirmed by the dashboard | not confirmed (reason stated) "
                  "| refused before moving | unaccounted |",
              "|---|---|---|---|---|---|"]  # fmt: skip
    for kind in KINDS:
        runs = by_kind.get(kind, [])
        if not runs:
            continue
        rtde = sum(r["rest_source"] == "rtde" for r in runs)
        dash = sum(r["rest_source"] == "dashboard" for r in runs)
        stated = sum(r["rest_confirmed"] is False for r in runs)
        refused = sum(
            r["rest_confirmed"] is not True and r["rest_confirmed"] is not False and r["accounted"] for r in runs
        )
        lines.append(f"| {kind} | {rtde} | {dash} | {stated} | {refused} | {sum(not r['accounted'] for r in runs)} |")
    lines += [
        "",
        "| time to confirmed rest (s, from the stop's start) | runs | p50 | p90 | p99 | max |",
        "|---|---|---|---|---|---|",
    ]
    for source in ("rtde", "dashboard"):
        values = [r["rest_confirmed_after_s"] for r in rows if r["rest_source"] == source]
        lines.append(f"| confirmed by {source} | {len(values)} | {_quantiles(values)} |")
    for kind in KINDS:
        values = [r["rest_confirmed_after_s"] for r in by_kind.get(kind, []) if r["rest_confirmed"]]
        if values:
            lines.append(f"| {kind} | {len(values)} | {_quantiles(values)} |")
    reasons = Counter(
        re.sub(r"\(.*", "", r["rest_not_confirmed"]).strip() for r in rows if r["rest_confirmed"] is False
    )
    if reasons:
        lines += ["", "| not confirmed at rest: the stated reason | runs |", "|---|---|"]
        lines += [f"| {reason} | {n} |" for reason, n in reasons.most_common()]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--jobs", type=int, default=1, help="episodes at a time (each with its own emulator)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("fault_soak"))
    parser.add_argument("--own-series", action="store_true", help="each arm at its own rate (e-Series: 500 Hz)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    ENV["PYTHONPYCACHEPREFIX"] = str((args.out / "pycache").resolve())
    hosts: queue.Queue[str] = queue.Queue()
    for k in range(args.jobs):
        hosts.put(f"127.0.3.{k + 1}")

    def one(episode: int) -> dict:
        host = hosts.get()
        try:
            row = run_episode(episode, args.seed, host, args.out, args.own_series)
        finally:
            hosts.put(host)
        print(f"{episode:4d} {row['robot']:6s} {row['fault']:17s} exit {row['exit_code']}: {row['ending']}; "
              f"rest {row['rest_confirmed_by'] or row['rest_not_confirmed'] or '-'} "
              f"{row['rest_confirmed_after_s'] or ''}", file=sys.stderr, flush=True)  # fmt: skip
        return row

    started = time.monotonic()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(one, range(args.episodes)))
    with (args.out / "episodes.csv").open("w", newline="") as sink:
        writer = csv.DictWriter(sink, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    retried = sum(r["retries"] > 0 for r in rows)
    print(f"{len(rows)} episodes, --jobs {args.jobs}, seed {args.seed}, {time.monotonic() - started:.0f} s; "
          f"{retried} started again after a process died before the episode began\n")  # fmt: skip
    print(tables(rows))
    return 0 if all(r["accounted"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
