"""SNAC sensitivity table for docs/snac.md: the defaults, each option changed one at a time.

Every configuration is one ``snac-gym evaluate`` run (kinematic engine, seed 0, default
horizons reach 12 s / track 20 s, no effort matching), run through the CLI so the command of
each row is the one a reader would type. From each ``results.csv`` it prints, per task:

* V/N: the mean of ``cost`` over the samples (the Table I entry of ``summary.csv``);
* V/N without the jump from rest: the mean of ``cost − cost_smoothness_start`` (u₋₁ = u₀);
* HJB cost: the mean of ``cost_error + cost_effort`` (∫ eᵀQe + uᵀRu, the cost the critic
  approximates, without the u̇ term);
* success rate (reach: final error ≤ 1 mm; track: mean error over the second half ≤ 5 mm);
* median final error (reach) or median ``mean_error_2nd_half`` (track), mm;
* median ``max_abs_u`` (each rollout's peak |uⱼ|), rad/s.

Usage (about 6 s per configuration on 2 workers; the runs use the code of the checkout that
holds this script, through ``python -m snac_gym.apps.cli`` with that checkout as working directory)::

    .venv/bin/python docs/scripts/snac_sensitivity.py --out /tmp/sens --samples 200

``--reuse`` reads folders that already hold a ``results.csv`` instead of re-running them.
"""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[2]

#: (name, --param values, note). The first row is the defaults.
SNAC_CONFIGS: list[tuple[str, list[str], str]] = [
    ("defaults", [], "uniform Ŵ₀, ξ = [e; x_d], α per s, k in s, no freeze, euler"),
    ("identity", ["initial_weights=identity"], "Ŵ₀ = c on squared terms (c = 2 reach, 20 track)"),
    ("centred", ["tracking_state=centred"], "ξ = [e; x_d − x_c] (track only)"),
    ("per_step", ["learning_rate_unit=per_step"], "α per control step"),
    ("steps", ["schedule_clock=steps"], "k counts steps"),
    ("freeze", ["freeze_when_saturated=true"], "anti-windup"),
    ("euler_updated", ["weight_update=euler_updated"], "u from Ŵₖ₊₁"),
    ("zoh", ["weight_update=zoh"], "law integrated over the period"),
    (
        "per_step+steps+freeze",
        ["learning_rate_unit=per_step", "schedule_clock=steps", "freeze_when_saturated=true"],
        "the earliest default's laws, with ξ = [e; x_d]",
    ),
    (
        "per_step+steps+freeze+centred",
        ["learning_rate_unit=per_step", "schedule_clock=steps", "freeze_when_saturated=true", "tracking_state=centred"],
        "the earliest default exactly",
    ),
    (
        "identity+centred",
        ["initial_weights=identity", "tracking_state=centred"],
        "the previous default (before the paper-faithful one)",
    ),
]


def folder(name: str) -> str:
    """An ASCII folder name for a configuration name."""
    for greek, latin in (("ν", "nu"), ("σ₀", "sigma0"), ("ε", "eps")):
        name = name.replace(greek, latin)
    return re.sub(r"[^A-Za-z0-9.-]+", "_", name)


def command(out: Path, controller: str, params: Sequence[str], samples: int, workers: int) -> list[str]:
    """The ``snac-gym evaluate`` command line of one configuration."""
    args = [
        "snac-gym",
        "evaluate",
        "--out",
        str(out),
        "--controllers",
        controller,
        "--samples",
        str(samples),
        "--workers",
        str(workers),
        "--no-match-effort",
        "--no-progress",
    ]
    for param in params:
        args += ["--param", f"{controller}.{param}"]
    return args


def run(out: Path, controller: str, params: Sequence[str], samples: int, workers: int, reuse: bool) -> pd.DataFrame:
    """Run one configuration (or reuse its folder) and return its ``results.csv``."""
    results = out / "results.csv"
    if not (reuse and results.exists()):
        if out.exists() and any(out.iterdir()):
            raise SystemExit(f"{out} exists and is not empty; remove it or pass --reuse")
        args = command(out, controller, params, samples, workers)
        print("$", shlex.join(args), file=sys.stderr, flush=True)
        # `python -m snac_gym.apps.cli` from the repository root: the code of this checkout runs,
        # whatever copy of the package the interpreter has installed.
        subprocess.run(
            [sys.executable, "-m", "snac_gym.apps.cli", *args[1:]], check=True, cwd=REPO, stdout=subprocess.DEVNULL
        )
    return pd.read_csv(results)


def figures(results: pd.DataFrame, controller: str) -> dict[str, dict[str, float]]:
    """Per task: the figures of the table, from one run's ``results.csv``."""
    table: dict[str, dict[str, float]] = {}
    for task, rows in results[results.controller == controller].groupby("task"):
        accuracy = rows.final_error if task == "reach" else rows.mean_error_2nd_half
        table[str(task)] = {
            "n": len(rows),
            "V/N": rows.cost.mean(),
            "V/N no jump": (rows.cost - rows.cost_smoothness_start).mean(),
            "jump": rows.cost_smoothness_start.mean(),
            "HJB cost": (rows.cost_error + rows.cost_effort).mean(),
            "success": rows.success.astype(bool).mean(),
            "median error mm": 1e3 * accuracy.median(),
            "median max|u|": rows.max_abs_u.median(),
        }
    return table


def markdown(rows: list[tuple[str, dict[str, dict[str, float]]]], task: str) -> str:
    """One markdown table (one task) from ``(name, figures)`` rows."""
    error = "median final error (mm)" if task == "reach" else "median 2nd-half mean error (mm)"
    lines = [
        f"| {task} | V/N | V/N without jump | jump share | HJB cost | success | {error} | median max \\|u\\| (rad/s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, table in rows:
        f = table[task]
        lines.append(
            f"| {name} | {f['V/N']:.2f} | {f['V/N no jump']:.2f} | {100 * f['jump'] / f['V/N']:.0f} % | "
            f"{f['HJB cost']:.3f} | {100 * f['success']:.1f} % | {f['median error mm']:.3g} | "
            f"{f['median max|u|']:.3f} |"
        )
    return "\n".join(lines)


def main(configs: list[tuple[str, list[str], str]], controller: str, argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="parent folder of one run folder per configuration")
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--reuse", action="store_true", help="read existing results.csv instead of re-running")
    args = parser.parse_args(argv)
    rows = []
    for name, params, _ in configs:
        results = run(args.out / folder(name), controller, params, args.samples, args.workers, args.reuse)
        rows.append((name, figures(results, controller)))
    print(f"{args.samples} samples per task, seed 0, kinematic engine, reach 12 s, track 20 s, --no-match-effort\n")
    print("| name | --param | what |\n|---|---|---|")
    for name, params, note in configs:
        print(f"| {name} | {' '.join(f'`{controller}.{p}`' for p in params) or '—'} | {note} |")
    for task in ("reach", "track"):
        print()
        print(markdown(rows, task))


if __name__ == "__main__":
    main(SNAC_CONFIGS, "snac")
