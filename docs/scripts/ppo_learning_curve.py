"""The PPO learning curve measured by the optimality gap: each kept checkpoint of a training run
against the per-sample optimum on a fixed validation set.

    python docs/scripts/ppo_learning_curve.py --run reach=runs/ppo26/reach --run track=runs/ppo26/track \
        --out docs/ppo/optimality_gap.png --table runs/ppo26/validation.csv

For each task the validation set is ``--samples`` samples of seed ``--seed`` (not the evaluator's
default seeds 0 and 1). The optimum (``optimal``) is solved once per task; every checkpoint in
``RUN/checkpoints/`` (written when the config has ``evaluation.keep_checkpoints``) is then run by
the evaluator on the same samples as ``ppo`` with ``--param ppo.model_path=...``, under the cost
it was trained on (``--cost hjb --q-scale 4``, no effort matching). The figure plots the median
over samples of the checkpoint's cost over the optimum's, less 1, against env steps and wall-clock
training time (from ``RUN/evaluations.csv``), as the optimality gap (the ratio − 1); the table adds
the success rate.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

COST = ["--cost", "hjb", "--q-scale", "4", "--no-match-effort", "--no-progress", "--workers", "1"]


def evaluate(task: str, seed: int, samples: int, out: Path, controllers: str, *params: str) -> pd.DataFrame:
    if not (out / "results.csv").exists():
        command = [
            sys.executable,
            "-m",
            "snac_gym.apps.cli",
            "evaluate",
            "--task",
            task,
            "--seed",
            str(seed),
            "--samples",
            str(samples),
            "--controllers",
            controllers,
            "--out",
            str(out),
            *COST,
            *params,
        ]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return pd.read_csv(out / "results.csv")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", action="append", required=True, help="TASK=RUN_FOLDER (repeatable)")
    parser.add_argument("--seed", type=int, default=99)
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--work", default="runs/ppo_validation", help="folder for the evaluator's runs")
    parser.add_argument("--out", default="docs/ppo/optimality_gap.png")
    parser.add_argument("--table", default=None, help="also write the rows as CSV here")
    args = parser.parse_args()
    work = Path(args.work)
    rows = []
    for item in args.run:
        task, folder = item.split("=", 1)
        folder = Path(folder)
        optimum = evaluate(task, args.seed, args.samples, work / f"{task}-optimal", "optimal")
        optimum = optimum[optimum.controller == "optimal"].set_index("sample")
        walls = {int(r["timesteps"]): float(r["wall_time_s"]) for r in csv.DictReader(open(folder / "evaluations.csv"))}
        for checkpoint in sorted((folder / "checkpoints").glob("*.npz")):
            steps = int(checkpoint.stem)
            result = evaluate(
                task,
                args.seed,
                args.samples,
                work / f"{task}-{checkpoint.stem}",
                "ppo",
                "--param",
                f"ppo.model_path={checkpoint.resolve()}",
            )
            result = result[result.controller == "ppo"].set_index("sample")
            ratio = result["cost_hjb"] / optimum.loc[result.index, "cost_hjb"]
            rows.append(
                {
                    "task": task,
                    "timesteps": steps,
                    "wall_time_s": walls.get(steps, np.nan),
                    "median_ratio": float(ratio.median()),
                    "p90_ratio": float(ratio.quantile(0.9)),
                    "success": float(result["success"].mean()),
                    "file": str(checkpoint),
                }
            )
            print(
                f"{task} {steps:>9d} steps: median ratio {rows[-1]['median_ratio']:.3f}, "
                f"success {100 * rows[-1]['success']:.1f} %",
                flush=True,
            )
    table = pd.DataFrame(rows)
    if args.table:
        table.to_csv(args.table, index=False)
    plot(table, Path(args.out), args.samples, args.seed)


def plot(table: pd.DataFrame, out: Path, samples: int, seed: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    for task, colour in (("reach", "tab:blue"), ("track", "tab:orange")):
        rows = table[table.task == task].sort_values("timesteps")
        if rows.empty:
            continue
        gap = rows.median_ratio - 1.0  # the optimality gap: cost / optimum − 1
        axes[0].plot(rows.timesteps / 1e6, gap, "o-", color=colour, label=task)
        axes[1].plot(rows.wall_time_s / 60, gap, "o-", color=colour, label=task)
    ticks = [0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10]
    for ax in axes:
        ax.axhline(0.5, color="grey", ls="--", lw=1)
        ax.set_yscale("log")
        ax.set_yticks(ticks)
        ax.set_yticklabels([f"{t:g}" for t in ticks])
        ax.minorticks_off()
        ax.grid(alpha=0.3)
    axes[0].text(0.45, 0.54, "goal ≤ 0.5", color="grey", transform=axes[0].get_yaxis_transform())
    axes[0].set_xlabel("env steps (millions)")
    axes[1].set_xlabel("wall-clock training time (min),\nperiodic PyBullet evaluations included")
    axes[0].set_ylabel("median optimality gap (cost / optimum − 1)")
    axes[0].legend()
    fig.suptitle(
        f"PPO checkpoints against the per-sample optimum ({samples} validation samples, seed {seed}, HJB cost, Q = 4I)",
        fontsize=10,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
