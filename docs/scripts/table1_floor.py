"""The floor of the README's main command (Table I) on this machine, beside the measured time.

    python docs/scripts/table1_floor.py RUN [RUN_WARM] [--workers 2]

RUN is the folder of a finished ``snac-gym evaluate`` of the README's main command with empty caches (its
``calibration.json`` holds the searches where it matched the knobs; at the shipped knobs it searched nothing), RUN_WARM
(optional) one run with the calibration and reference caches warm. The floor is the work such a run cannot avoid, at the
rate this machine does it:

* **passes**: every controller on every sample once at full horizon, timed as ``run_job`` (the evaluator's
  lockstep rollout and the metrics of its rows) on one core, in process, on a chunk of the run's own samples
  at the run's matched knob, best of 3 after a warm-up; the full set's steps at that rate, shared by the
  workers;
* **searches**: the knob evaluations the run's searches made (``calibration.json``: evaluations ×
  screening samples × search steps, plus the 20-sample probe at full horizon), at the same rate;
* **reference**: ``run_optimal_job`` without the cache (every start, its screening, the winner's solve and
  the replay), timed in process on one core on the first ``REFERENCE_SAMPLES`` samples of each task and
  scaled to the set (``optimal_solve_time`` counts the winning solve only), shared by the workers.

Everything else (process start, sample drawing, job dispatch, parquet parts, reports, plots) is overhead.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pandas as pd
from _reference_runs import reference_job, run_setting
from snac_gym.evaluation.execution.jobs import RolloutJob, run_job
from snac_gym.evaluation.execution.passes import OPTIMAL_CHUNK_SIZE
from snac_gym.evaluation.reference.optimum import OptimalJob, run_optimal_job
from threadpoolctl import threadpool_limits

CHUNK = 250  # samples per timed job (the evaluator's chunks are 500)
PROBE = 20
#: The run's own reference job size: in a smaller job the batched rollouts' per-step overheads are shared by fewer
#: samples (40 samples overstated it: 41.6 and 51.5 ms a reach and a track sample, against 34.6 and 28.6 ms at 250).
REFERENCE_SAMPLES = OPTIMAL_CHUNK_SIZE


def rates(run: Path) -> dict[tuple[str, str], float]:
    """Steps per second of ``run_job`` on one core for each (task, controller) of ``run`` at its knob."""
    config, _, samples, convention = run_setting(run)
    results = pd.read_parquet(run / "results.parquet")
    out: dict[tuple[str, str], float] = {}
    for (task, controller), rows in results.groupby(["task", "controller"], sort=False):
        if controller == "optimal":
            continue
        knob, value = rows["effort_parameter"].iloc[0], rows["effort_value"].iloc[0]
        kwargs = dict(config["controller_kwargs"].get(controller, {}))
        if isinstance(knob, str) and pd.notna(value):
            kwargs[knob] = float(value)
        chunk = tuple(samples[task][:CHUNK])
        job = RolloutJob(task, controller, kwargs, chunk, tuple(range(len(chunk))), config["steps"][task], config["dt"],
                         config["robot"], convention=convention)  # fmt: skip
        run_job(job)  # compile and warm up
        best = min(_timed(job) for _ in range(3))
        out[(task, controller)] = len(chunk) * job.steps / best
        print(f"  {task:5s} {controller:9s} {out[(task, controller)] / 1e6:6.3f} M steps/s")
    return out


def reference_seconds(run: Path) -> float:
    """Seconds of one core to solve every reference row of ``run``, from a timed subset of each task."""
    config, _, samples, convention = run_setting(run)
    total = 0.0
    for task, task_samples in samples.items():
        job = reference_job(config, task, task_samples, REFERENCE_SAMPLES, convention)
        seconds = _timed(job)
        total += seconds * len(task_samples) / len(job.samples)
        print(f"  {task:5s} optimal   {seconds / len(job.samples) * 1e3:6.1f} ms per sample")
    return total


def _timed(job: object) -> float:
    started = time.perf_counter()
    run_optimal_job(job) if isinstance(job, OptimalJob) else run_job(job)
    return time.perf_counter() - started


def floor(run: Path, warm: Path | None = None, workers: int = 2) -> dict[str, float]:
    """The floor of ``run`` (and of ``warm``) in seconds beside their own ``timings.json`` totals: ``passes``,
    ``searches`` and ``reference`` (each shared by ``workers``), ``cold_floor``, ``cold_total``, and with ``warm``
    ``warm_floor`` (the passes: its knobs and reference rows are read, not made) and ``warm_total``."""
    with threadpool_limits(1):
        per_second = rates(run)
        reference = reference_seconds(run)
    manifest = json.loads((run / "run.json").read_text())
    results = pd.read_parquet(run / "results.parquet")
    counts = results.groupby(["task", "controller"]).size()
    pass_seconds = sum(counts[key] * manifest["steps"][key[0]] / rate for key, rate in per_second.items())
    # A run at the shipped or cached knobs searched nothing (no calibration.json): its floor has no searches.
    searched = run / "calibration.json"
    calibration = json.loads(searched.read_text()) if searched.is_file() else {}
    search_seconds = 0.0
    for key, record in calibration.items():
        if not isinstance(record, dict) or "evaluations" not in record:
            continue
        task, controller = key.split("/")[:2]
        steps = len(record["evaluations"]) * record["screening_samples"] * record["search_steps"]
        steps += PROBE * manifest["steps"][task]
        search_seconds += steps / per_second[(task, controller)]
    out = {
        "passes": pass_seconds / workers,
        "searches": search_seconds / workers,
        "reference": reference / workers,
        "cold_floor": (pass_seconds + search_seconds + reference) / workers,
        "cold_total": json.loads((run / "timings.json").read_text())["total"],
    }
    if warm is not None:
        out["warm_floor"] = pass_seconds / workers
        out["warm_total"] = json.loads((warm / "timings.json").read_text())["total"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("warm", type=Path, nargs="?")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    found = floor(args.run, args.warm, args.workers)
    print(
        f"passes {found['passes']:.1f} s, searches {found['searches']:.1f} s, "
        f"reference {found['reference']:.1f} s on {args.workers} workers"
    )
    cold, total = found["cold_floor"], found["cold_total"]
    print(f"cold: floor {cold:.1f} s, measured {total:.1f} s (ratio {total / cold:.2f})")
    if args.warm is not None:
        warm, total = found["warm_floor"], found["warm_total"]
        print(f"warm: floor {warm:.1f} s, measured {total:.1f} s (ratio {total / warm:.2f})")


if __name__ == "__main__":
    main()
