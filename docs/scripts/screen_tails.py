"""Where the reference's screens spend their Gauss-Newton steps: the candidates that reach no known basin within the
screen's steps and are solved on the coarse grid to the end, and how fast those solves converge, one core.

    python docs/scripts/screen_tails.py RUN [SAMPLES] [--gauss-newton]

RUN is the folder of a finished ``snac-gym evaluate`` (its ``run.json`` and ``samples.csv``); SAMPLES (default 250, the
evaluator's reference job size) of each task are solved as one ``run_optimal_job`` without the cache, after a two-sample
warm-up. For each task it prints the screens, the coarse solves that follow a screen (those that ended in a known
basin, elsewhere, or against a limit), their Gauss-Newton iterations and their share of the job's directions and time,
and the contraction of their steps: the median over those solves of ‖δₖ₊₁‖/‖δₖ‖ (max norm) over each solve's last
half. A ratio near 1 with full steps taken is Gauss-Newton's linear convergence where the residuals are large (the
neglected Σ eᵢ∇²fᵢ of the exact Hessian is not small); docs/benchmarks-log.md ("The main command")
has the figures. ``--gauss-newton``: the solves take Gauss-Newton's steps only (``multistart.NEWTON`` off), as before
the reference took Newton's.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _reference_runs import reference_job, run_setting
from snac_gym.evaluation.reference import multistart
from snac_gym.evaluation.reference.optimum import run_optimal_job
from threadpoolctl import threadpool_limits

from snac_gym.control.gauss_newton import GaussNewtonSolver


class Recorder:
    """Counts every Gauss-Newton direction, and the steps and outcome of each coarse solve that follows a screen."""

    def __init__(self) -> None:
        self.directions = 0
        self.tail: list[float] | None = None  # step norms of the tail solve running now
        self.tails: list[dict[str, Any]] = []

    def direction(self, original: Any) -> Any:
        def wrapped(solver: Any, *args: Any, **kwargs: Any) -> np.ndarray:
            step = original(solver, *args, **kwargs)
            self.directions += 1
            if self.tail is not None:
                self.tail.append(float(np.abs(step).max()))
            return step

        return wrapped

    def screen(self, original: Any) -> Any:
        def wrapped(q0: Any, coarse_x: Any, kinematics: Any, dt: float, convention: Any, coarse_solve: Any,
                    in_basin: Any, start: Any) -> Any:  # fmt: skip
            def tail_solve(**kwargs: Any) -> Any:
                self.tail, started = [], time.perf_counter()
                try:
                    solution = coarse_solve(**kwargs)
                finally:
                    steps, self.tail = self.tail, None
                half = steps[len(steps) // 2 :]
                ratios = [b / a for a, b in zip(half, half[1:], strict=False) if a > 0]
                self.tails.append({
                    "seconds": time.perf_counter() - started, "directions": len(steps),
                    "ended": "limit" if solution.bounded else ("basin" if in_basin(solution.commands) else "elsewhere"),
                    "contraction": float(np.median(ratios)) if ratios else float("nan"),
                })  # fmt: skip
                return solution

            return original(q0, coarse_x, kinematics, dt, convention, tail_solve, in_basin, start)

        return wrapped


def main() -> None:
    arguments = [a for a in sys.argv[1:] if a != "--gauss-newton"]
    multistart.NEWTON = "--gauss-newton" not in sys.argv
    run, count = Path(arguments[0]), int(arguments[1]) if len(arguments) > 1 else 250
    config, _, samples, convention = run_setting(run)
    recorder = Recorder()
    GaussNewtonSolver.direction = recorder.direction(GaussNewtonSolver.direction)  # type: ignore[method-assign]
    screens = [0]
    screen = recorder.screen(multistart._coarse_screen)

    def counted(*args: Any) -> Any:
        screens[0] += 1
        return screen(*args)

    multistart._coarse_screen = counted
    with threadpool_limits(1):
        for task, task_samples in samples.items():
            job = reference_job(config, task, task_samples, count, convention)
            recorder.directions, recorder.tails[:], screens[0] = 0, [], 0
            started = time.perf_counter()
            run_optimal_job(job)
            total = time.perf_counter() - started
            tails = recorder.tails
            print(f"{task}: {len(job.samples)} samples in {total:.2f} s, {recorder.directions} Gauss-Newton "
                  f"directions, {screens[0]} screens")  # fmt: skip
            for ended in ("basin", "elsewhere", "limit"):
                group = [t for t in tails if t["ended"] == ended]
                if group:
                    print(f"  coarse solves after a screen that ended {ended:9s}: {len(group):4d}, "
                          f"{np.mean([t['directions'] for t in group]):5.1f} directions each, "
                          f"{sum(t['seconds'] for t in group):5.2f} s")  # fmt: skip
            directions = sum(t["directions"] for t in tails)
            contraction = [t["contraction"] for t in tails if np.isfinite(t["contraction"])]
            low, median, high = np.percentile(contraction, [25, 50, 75]) if contraction else [float("nan")] * 3
            print(f"  all of them: {directions / max(recorder.directions, 1):.0%} of the directions, "
                  f"{sum(t['seconds'] for t in tails) / total:.0%} of the time; step contraction over each one's "
                  f"last half, median {median:.2f} (quartiles {low:.2f}-{high:.2f})")  # fmt: skip


if __name__ == "__main__":
    main()
