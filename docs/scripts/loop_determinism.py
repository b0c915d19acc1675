"""The 500 Hz real-arm loop on a busy host: each determinism measure on and off.

Against the emulated e-Series controller (500 Hz, its cycle at SCHED_FIFO 20, as a real
controller's is), with a CPU hog beside it (a busy Python loop at normal priority, one per
``--hogs``), runs ``run_real_episode`` (what ``snac-gym real --series e`` does: the real ur_rtde
client in its child process) for ``--seconds`` of the reach demo once per configuration, each in
a fresh process so that no measure leaks into the next:

* ``none``: normal scheduling, memory not locked, garbage collector on, stream log formatted inline;
* ``log-process``: only the stream log written by its own process;
* ``gc-frozen``: only the garbage collector frozen and disabled for the episode;
* ``mlockall``: only the process's memory locked;
* ``fifo``: only SCHED_FIFO 20 (the ur_rtde client inherits it);
* ``all``: every measure (``snac-gym real --rt-priority 20``);
* ``all-but-log-process``, ``all-but-gc-frozen``, ``all-but-mlockall``: every measure but one.

To measure the whole 20 s whatever happens, the host's timing rules (late loop, stall, stale
state) are loosened and the controller's watchdog is set to 25 periods (50 ms) instead of 5;
the default late-loop rule (3 periods over 1.5 × dt within 25) and stall rule (one period over
40 ms) are then replayed on the recorded periods: "stopped at" is the period at which the
default rules would have stopped the run (none: they would not have). Then ``--allocations``
counts what one ``policy.act`` and one env step allocate (``tracemalloc``), on the simulated
connection.

    .venv/bin/python docs/scripts/loop_determinism.py --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

CONFIGS = {
    "none": {"tuning": {}, "journal_writer": "inline"},
    "log-process": {"tuning": {}, "journal_writer": "process"},
    "gc-frozen": {"tuning": {"freeze_gc": True}, "journal_writer": "inline"},
    "mlockall": {"tuning": {"lock_memory": True}, "journal_writer": "inline"},
    "fifo": {"tuning": {"rt_priority": 20}, "journal_writer": "inline"},
    "all": {"tuning": {"rt_priority": 20, "lock_memory": True, "freeze_gc": True}, "journal_writer": "process"},
    # each measure off with the others on: what it adds next to real-time scheduling
    "all-but-log-process": {
        "tuning": {"rt_priority": 20, "lock_memory": True, "freeze_gc": True},
        "journal_writer": "inline",
    },
    "all-but-gc-frozen": {"tuning": {"rt_priority": 20, "lock_memory": True}, "journal_writer": "process"},
    "all-but-mlockall": {"tuning": {"rt_priority": 20, "freeze_gc": True}, "journal_writer": "process"},
}


def _one(config: str, seconds: float) -> None:
    """Child: one episode under ``config``; prints its timing as JSON."""
    import functools

    import snac_gym.apps.real as run_module
    from snac_gym.apps.real import run_real_episode
    from snac_gym.real import SafetyLimits
    from snac_gym.real.loop_tuning import LoopTuning

    spec = CONFIGS[config]
    run_module.URRTDEConnection = functools.partial(run_module.URRTDEConnection, watchdog_periods=25)
    loose = SafetyLimits(max_missed_deadlines=25, max_period=1.0, max_stale_periods=50)
    with tempfile.TemporaryDirectory() as out:
        try:
            result = run_real_episode(
                task="reach", controller="snac", out_dir=out, connection="rtde", host="127.0.0.1", series="e",
                steps=round(seconds * 500), plots=False, safety=loose, tuning=LoopTuning(**spec["tuning"]),
                journal_writer=spec["journal_writer"],
            )  # fmt: skip
        except Exception as exc:
            summary = (
                json.loads(next(Path(out).glob("*real.json")).read_text()) if list(Path(out).glob("*real.json")) else {}
            )
            print(json.dumps({"config": config, "error": f"{type(exc).__name__}: {exc}",
                              "client_output": summary.get("client_output", [])}))  # fmt: skip
            return
        periods = np.loadtxt(os.path.join(out, "reach_snac_timing.csv"), delimiter=",", skiprows=1)[:, 1]
    print(json.dumps({
        "config": config, "stop_reason": result.stop_reason, "notes": result.tuning_notes,
        "periods": len(periods), "p50": float(np.percentile(periods, 50)), "p99": float(np.percentile(periods, 99)),
        "max_after_first": float(periods[1:].max()), "late": int(np.sum(periods[1:] > 3.0)),
        "mean": float(periods.mean()), "default_rules_stop": _default_rules_stop(periods / 1e3),
    }))  # fmt: skip


def _default_rules_stop(periods: np.ndarray) -> int | None:
    """The period at which the default late-loop and stall rules would have stopped the run (the first is not
    counted)."""
    from snac_gym.model.kinematics import Kinematics
    from snac_gym.real import SafetyLayer, SafetyLimits

    layer = SafetyLayer(Kinematics("ur10"), SafetyLimits(), 1.0 / 500.0)
    for k, period in enumerate(periods[1:], start=2):
        if layer.record_period(float(period)) is not None:
            return k
    return None


def _command(repeats: int, seconds: float, hogs: int) -> None:
    """``snac-gym real --series e --rt-priority 20`` as a user runs it (default safety, 5-period watchdog)."""
    from snac_gym.real.emulator.process import EmulatorProcess

    hog_processes = [_hog() for _ in range(hogs)]
    try:
        with EmulatorProcess(series="e", rt_priority=20, bind_timeout=90.0) as emu:
            for k in range(repeats):
                emu.reset()
                load = os.getloadavg()[0]
                with tempfile.TemporaryDirectory() as out:
                    command = [sys.executable, "-m", "snac_gym.apps.cli", "real", "--host", "127.0.0.1",
                               "--series", "e", "--rt-priority", "20", "--task", "reach", "--controller", "snac",
                               "--steps", str(round(seconds * 500)), "--out", out]  # fmt: skip
                    child = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 120)
                lines = (child.stdout + child.stderr).splitlines()
                shown = [
                    ln.strip()
                    for ln in lines
                    if ln.strip().startswith(("loop period", "stopped", "no safety", "error", "final error"))
                ]
                print(
                    f"run {k + 1}, load average {load:.1f}, exit {child.returncode}: " + " | ".join(shown), flush=True
                )
    finally:
        for hog in hog_processes:
            hog.kill()
            hog.wait()


def _hog() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def _measure(configs: list[str], repeats: int, seconds: float, hogs: int) -> list[dict]:
    from snac_gym.real.emulator.process import EmulatorProcess

    rows = []
    hog_processes = [_hog() for _ in range(hogs)]
    try:
        with EmulatorProcess(series="e", rt_priority=20, bind_timeout=90.0) as emu:
            for _ in range(repeats):
                for config in configs:
                    emu.reset()
                    load = os.getloadavg()[0]
                    child = subprocess.run(
                        [sys.executable, __file__, "--one", config, "--seconds", str(seconds)],
                        capture_output=True, text=True, timeout=seconds + 120,
                    )  # fmt: skip
                    lines = [ln for ln in child.stdout.splitlines() if ln.startswith("{")]
                    if not lines:
                        row = {"config": config, "error": (child.stderr.strip().splitlines() or ["?"])[-1]}
                    else:
                        row = json.loads(lines[-1])
                    row["load"] = load
                    rows.append(row)
                    print(_format(row), flush=True)
                    time.sleep(1.0)
    finally:
        for hog in hog_processes:
            hog.kill()
            hog.wait()
    return rows


def _format(row: dict) -> str:
    if "error" in row:
        said = f" (client's last lines: {' / '.join(row['client_output'][-3:])})" if row.get("client_output") else ""
        return f"| {row['config']} | {row['load']:.1f} | error: {row['error']}{said} |"
    stop = row["default_rules_stop"] or "none"
    if row["stop_reason"]:
        stop = f"{stop}; ended by: {row['stop_reason']}"
    return (
        f"| {row['config']} | {row['load']:.1f} | {row['periods']} | {row['mean']:.3f} | {row['p50']:.3f} | "
        f"{row['p99']:.3f} | {row['max_after_first']:.2f} | {row['late']} | {stop} |"
        + (f" {'; '.join(row['notes'])}" if row["notes"] else "")
    )


def _allocations(samples: int = 2000) -> None:
    """Bytes one ``policy.act`` and one env step allocate at their peak (tracemalloc), median over ``samples`` calls."""
    from snac_gym.policies import make_policy
    from snac_gym.policies.base import PolicyContext
    from snac_gym.real import RealUREnv, SafetyLimits, SimulatedConnection

    env = RealUREnv("reach", SimulatedConnection(realtime=False, frequency=500.0),
                    safety=SafetyLimits(max_period=10.0, max_missed_deadlines=25), max_steps=10 * samples)  # fmt: skip
    policy = make_policy("snac", PolicyContext.for_controller(env))
    obs, _ = env.reset(options=env.task.demo_options())
    policy.reset(seed=0)
    for _ in range(50):  # warm-up: caches, first-call imports
        obs = env.step(policy.act(obs))[0]
    act_bytes, step_bytes = [], []
    tracemalloc.start()
    for _ in range(samples):
        for call, sink in ((lambda: policy.act(obs), act_bytes), (lambda: env.step(action), step_bytes)):
            start = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            value = call()
            sink.append(tracemalloc.get_traced_memory()[1] - start)
            if sink is act_bytes:
                action = value
            else:
                obs = value[0]
    tracemalloc.stop()
    print(f"allocated at the peak of one call, {samples} calls (snac, reach, simulated connection at 500 Hz):")
    print(f"  policy.act: median {np.median(act_bytes):.0f} B, max {max(act_bytes)} B")
    print(
        f"  env step (safety layer, costs, observation; the arm's own step included): "
        f"median {np.median(step_bytes):.0f} B, max {max(step_bytes)} B"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--one", help=argparse.SUPPRESS)
    parser.add_argument("--configs", default=",".join(CONFIGS), help="comma-separated, of: " + ", ".join(CONFIGS))
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--hogs", type=int, default=1, help="busy Python loops beside the run")
    parser.add_argument("--allocations", action="store_true", help="only count act's and step's allocations")
    parser.add_argument(
        "--command",
        action="store_true",
        help="run `snac-gym real --series e --rt-priority 20` as is (default safety and watchdog)",
    )
    args = parser.parse_args()
    if args.one:
        _one(args.one, args.seconds)
        return
    if args.allocations:
        _allocations()
        return
    if args.command:
        _command(args.repeats, args.seconds, args.hogs)
        return
    configs = args.configs.split(",")
    unknown = sorted(set(configs) - set(CONFIGS))
    if unknown:
        parser.error(f"unknown configuration(s) {unknown}; known: {', '.join(CONFIGS)}")
    print(f"{args.seconds:g} s reach at 500 Hz, {args.hogs} CPU hog(s), {os.cpu_count()} CPUs")
    print(
        "| config | load avg | periods | mean ms | p50 ms | p99 ms | max ms (after the first) | late | "
        "default rules stop at |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    _measure(configs, args.repeats, args.seconds, args.hogs)


if __name__ == "__main__":
    main()
