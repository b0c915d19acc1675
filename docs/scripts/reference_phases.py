"""Where a reference job's time goes: each step of ``_solve_job`` timed on the first samples of a run's set, one core.

    python docs/scripts/reference_phases.py RUN [SAMPLES]

RUN is the folder of a finished ``snac-gym evaluate`` (its ``run.json`` and ``samples.csv``); SAMPLES (default 250, the
evaluator's reference job size) of each task are solved as one ``run_optimal_job`` without the cache, after a two-sample
warm-up, with the steps of the multi-start wrapped by timers: the solves from rest, the own feedback starts, the
IK-branch and random starts (their IK apart), the screens and coarse solves of the starts (the screens' first
Gauss-Newton steps apart), the replay's metrics and the lower bound. A step's time includes the steps it calls; what
the steps leave of the total is the job's own bookkeeping. docs/benchmarks-log.md ("Two cuts in the reference's search")
has its figures.
"""

from __future__ import annotations

import functools
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from _reference_runs import reference_job, run_setting
from snac_gym.evaluation.reference import branches, multistart, optimum
from snac_gym.evaluation.reference.optimum import run_optimal_job
from threadpoolctl import threadpool_limits

#: (module, function, label) of each timed step.
STEPS = (
    (optimum, "solve_from_rest", "solves from rest"),
    (optimum, "own_start_commands", "own feedback starts"),
    (optimum, "branch_candidates", "IK-branch and random starts"),
    (branches, "branch_goals", "  of which their IK"),
    (multistart, "_coarse_screen", "screens and coarse solves"),
    (multistart, "gauss_newton", "  of which the screens' steps"),
    (optimum, "rollout_metrics", "replay metrics"),
    (optimum, "_lower_bounds", "lower bound"),
)


def timed(seconds: dict[str, float], label: str, function: Any) -> Any:
    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        started = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            seconds[label] += time.perf_counter() - started

    return wrapper


def main() -> None:
    run, count = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 250
    config, _, samples, convention = run_setting(run)
    seconds: dict[str, float] = defaultdict(float)
    for module, name, label in STEPS:
        setattr(module, name, timed(seconds, label, getattr(module, name)))
    with threadpool_limits(1):
        for task, task_samples in samples.items():
            job = reference_job(config, task, task_samples, count, convention)
            seconds.clear()
            started = time.perf_counter()
            run_optimal_job(job)
            print(f"{task}: {len(job.samples)} samples in {time.perf_counter() - started:.2f} s")
            for _, _, label in STEPS:
                print(f"  {label:30s} {seconds[label]:6.2f} s")


if __name__ == "__main__":
    main()
