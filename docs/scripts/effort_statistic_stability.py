"""How much each effort statistic's matched knob moves with the sample set (docs/evaluation.md,
"Equal effort: the statistic").

Rolls every controller over the first 1000 samples of seed 0 on a grid of knob values (gains in
4 % steps, ``q_scale`` in 10 % steps; 80 steps per rollout, which holds the peak of every one of
these controllers; SNAC, the reference, at its defaults over the full horizon), keeps each
rollout's peak, then for each statistic finds the matched knob (log-linear between grid points)
on all 1000 samples, on the first 200, and on 300 random subsets of 200.

    python docs/scripts/effort_statistic_stability.py [--peaks peaks.parquet]

With ``--peaks`` the rollouts are read from (or, the first time, written to) that file.
"""

from __future__ import annotations

import argparse
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from snac_gym.evaluation.execution.jobs import RolloutJob, run_job
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace

DT, N, SUBSET, DRAWS = 1 / 125, 1000, 200, 300
FULL_STEPS, STEPS = {"reach": 1500, "track": 2500}, 80
KNOBS = {
    "snac-hjb": ("q_scale", 6.0),
    "lqr": ("q_scale", 6.0),
    "rnn": ("gain", 1.0),
    "svf": ("gain", 1.0),
    "dls": ("gain", 1.0),
}
FACTORS = {"q_scale": [1.1**i for i in range(-14, 30)], "gain": [1.04**i for i in range(-8, 30)]}


def _peaks(args: tuple) -> pd.DataFrame:
    task, controller, kwargs, samples = args
    job = RolloutJob(
        task=task,
        controller=controller,
        kwargs=kwargs,
        samples=tuple(samples),
        seeds=tuple(policy_seed(0, task, s.index) for s in samples),
        steps=FULL_STEPS[task] if controller == "snac" else STEPS,
        dt=DT,
    )
    metrics = run_job(job).metrics[["sample", "peak_limit_fraction", "max_abs_u"]]
    return metrics.assign(task=task, controller=controller, knob=next(iter(kwargs.values())))


def roll_out() -> pd.DataFrame:
    kinematics = Kinematics("ur10")
    space = SampleSpace.for_robot(kinematics)
    work = []
    for task in ("reach", "track"):
        samples = generate_samples(kinematics, space, 0, task, range(N))
        halves = (samples[: N // 2], samples[N // 2 :])
        work += [(task, "snac", {"command_scale": 1.0}, half) for half in halves]
        for controller, (knob, base) in KNOBS.items():
            work += [(task, controller, {knob: base * f}, half) for f in FACTORS[knob] for half in halves]
    with ProcessPoolExecutor(2) as pool:
        return pd.concat(pool.map(_peaks, work), ignore_index=True)


def _matched(knobs: np.ndarray, efforts: np.ndarray, target: float) -> float:
    """The smallest knob whose effort reaches ``target``, log-linear between grid points."""
    above = np.flatnonzero(efforts >= target)
    if not len(above):
        return np.nan
    i = above[0]
    if i == 0 or efforts[i] == efforts[i - 1]:
        return float(knobs[i])
    fraction = (target - efforts[i - 1]) / (efforts[i] - efforts[i - 1])
    return float(np.exp(np.log(knobs[i - 1]) + fraction * (np.log(knobs[i]) - np.log(knobs[i - 1]))))


def statistics(P: np.ndarray, U: np.ndarray, p_ref: np.ndarray, u_ref: np.ndarray) -> dict:
    """Each statistic as ``indices → (efforts over the knob grid, the reference's target)``."""
    log_ratio = np.log(np.maximum(P, 1e-6)) - np.log(np.maximum(p_ref, 1e-6))
    return {
        "max": lambda i: (U[:, i].max(1), u_ref[i].max()),
        "median-peak": lambda i: (np.median(P[:, i], 1), np.median(p_ref[i])),
        "mean-peak": lambda i: (P[:, i].mean(1), p_ref[i].mean()),
        "peak-ratio": lambda i: (log_ratio[:, i].mean(1), 0.0),  # log of the geometric mean, target log 1
    }


def stability(peaks: pd.DataFrame) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    rows = []
    for task in ("reach", "track"):
        of_task = peaks[peaks["task"] == task].sort_values("sample")
        reference = of_task[of_task["controller"] == "snac"]
        p_ref, u_ref = reference["peak_limit_fraction"].to_numpy(), reference["max_abs_u"].to_numpy()
        for controller in KNOBS:
            mine = of_task[of_task["controller"] == controller]
            knobs = np.array(sorted(mine["knob"].unique()))
            grid = [mine[mine["knob"] == k] for k in knobs]
            P = np.stack([g["peak_limit_fraction"].to_numpy() for g in grid])
            U = np.stack([g["max_abs_u"].to_numpy() for g in grid])
            for name, statistic in statistics(P, U, p_ref, u_ref).items():
                full = _matched(knobs, *statistic(np.arange(N)))
                first = _matched(knobs, *statistic(np.arange(SUBSET))) / full - 1
                draws = np.array(
                    [_matched(knobs, *statistic(rng.choice(N, SUBSET, replace=False))) / full - 1 for _ in range(DRAWS)]
                )
                rows.append(
                    {
                        "task": task,
                        "controller": controller,
                        "statistic": name,
                        "knob_1000": full,
                        "first_200_pct": 100 * first,
                        "rms_pct": 100 * np.sqrt(np.nanmean(draws**2)),
                        "p95_pct": 100 * np.nanquantile(np.abs(draws), 0.95),
                        "unmatched": int(np.isnan(draws).sum()),
                    }
                )
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peaks", type=Path, help="parquet file of the rollouts' peaks (read if it exists)")
    args = parser.parse_args()
    # A target the knob grid cannot reach (max in reach) is NaN, and NaN-only columns warn.
    warnings.filterwarnings("ignore", category=RuntimeWarning)
    started = time.perf_counter()
    if args.peaks is not None and args.peaks.exists():
        peaks = pd.read_parquet(args.peaks)
    else:
        peaks = roll_out()
        if args.peaks is not None:
            peaks.to_parquet(args.peaks)
    result = stability(peaks)
    for value in ("rms_pct", "p95_pct", "first_200_pct"):
        print(f"\n{value}: matched knob on 200 samples relative to 1000, %")
        print(result.pivot_table(index=["task", "controller"], columns="statistic", values=value).round(1).to_string())
    print(f"\nwall time {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
