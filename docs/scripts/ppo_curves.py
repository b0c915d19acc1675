"""Training curves of PPO runs on the whole workspace: each kept checkpoint against the per-sample
optimum on validation samples, with the run's own periodic evaluations, and the checkpoint chosen.

    python docs/scripts/ppo_curves.py --run reach=runs/ppo_ws/reach10m --run track=runs/ppo_ws/track10m \
        --every 1000000 --fine-until 3200000 --out docs/figures/ppo_workspace_curves.png \
        --table runs/ppo_ws/validation.csv

Validation samples: ``--samples`` workspace samples (``--sample-space``) of evaluator seed ``--seed``
(default 1 000 000, the range the training pipeline's own evaluation uses; never the seeds results
are reported on). The optimum (``optimal``) is solved once per task; the checkpoints in
``RUN/checkpoints/`` every ``--fine-every`` steps up to ``--fine-until``, every ``--every`` steps after (and the last)
are run by the evaluator as ``ppo`` with ``--param ppo.model_path=...`` under the cost PPO was trained on
(``--cost hjb --q-scale 4``, no effort matching). Plotted against env steps: the median over samples of the checkpoint's
HJB cost over the optimum's, the evaluator's success rate (joint-limit rule included) and the share ending on
target (the error rule alone), and the periodic evaluation's success rate from ``RUN/evaluations.csv``
(``snac_gym.ppo.train.read_evaluations``; 10 PyBullet episodes, error rule only).

Chosen checkpoint per task: the lowest median ratio among those whose evaluator success is within
``--success-slack`` of the best checkpoint's.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pandas as pd

from snac_gym.ppo.train import read_evaluations

COST = ["--cost", "hjb", "--q-scale", "4", "--no-match-effort", "--no-progress"]
ERROR_RULE = {"reach": ("final_error", 1e-3), "track": ("mean_error_2nd_half", 5e-3)}


def evaluate(task: str, args: argparse.Namespace, out: Path, controllers: str, *params: str) -> pd.DataFrame:
    if not (out / "results.csv").exists():
        command = [
            sys.executable,
            "-m",
            "snac_gym.apps.cli",
            "evaluate",
            "--task",
            task,
            "--seed",
            str(args.seed),
            "--samples",
            str(args.samples),
            "--sample-space",
            args.sample_space,
            "--workers",
            str(args.workers),
            "--controllers",
            controllers,
            "--out",
            str(out),
            *COST,
            *params,
        ]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return pd.read_csv(out / "results.csv")


def checkpoints(folder: Path, every: int, fine_every: int, fine_until: int) -> list[Path]:
    """Every ``fine_every`` steps up to ``fine_until`` (the early checkpoints, where the best ones were), then every
    ``every``."""
    files = sorted((folder / "checkpoints").glob("*.npz"), key=lambda p: int(p.stem))
    chosen, next_mark = [], 0
    for path in files:
        if int(path.stem) >= next_mark:
            step = fine_every if int(path.stem) < fine_until else every
            chosen.append(path)
            next_mark = (int(path.stem) // step + 1) * step
    if files and files[-1] not in chosen:
        chosen.append(files[-1])
    return chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", action="append", required=True, help="TASK=RUN_FOLDER (repeatable)")
    parser.add_argument("--seed", type=int, default=1_000_000)
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--sample-space", default="workspace")
    parser.add_argument("--every", type=int, default=1_000_000, help="evaluate a checkpoint every this many steps")
    parser.add_argument("--fine-every", type=int, default=200_000, help="... this many steps up to --fine-until")
    parser.add_argument("--fine-until", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--success-slack", type=float, default=0.02)
    parser.add_argument("--work", default="runs/ppo_ws/validation", help="folder for the evaluator's runs")
    parser.add_argument("--out", default="docs/figures/ppo_workspace_curves.png")
    parser.add_argument("--table", default=None, help="also write the rows as CSV here")
    parser.add_argument("--success-floor", type=float, default=-2, help="lower end of the success axis, %%")
    parser.add_argument(
        "--baseline", default=None, help="a controller drawn as a line on the same samples (e.g. joint-goal)"
    )
    args = parser.parse_args()
    work = Path(args.work)
    rows, periodic, baselines = [], {}, {}
    for item in args.run:
        task, folder = item.split("=", 1)
        folder = Path(folder)
        periodic[task] = pd.DataFrame(read_evaluations(folder))
        names = "optimal" if args.baseline is None else f"optimal,{args.baseline}"
        reference = evaluate(
            task, args, work / f"{task}-{args.sample_space}-{args.seed}-{names.replace(',', '-')}", names
        )
        optimum = reference[reference.controller == "optimal"].set_index("sample")
        if args.baseline is not None:
            base = reference[reference.controller == args.baseline].set_index("sample")
            baselines[task] = (
                float((base["cost_hjb"] / optimum.loc[base.index, "cost_hjb"]).median()),
                float(base["success"].astype(bool).mean()),
            )
            print(
                f"{task} {args.baseline}: median ratio {baselines[task][0]:.3f}, success "
                f"{100 * baselines[task][1]:.0f} %"
            )
        column, limit = ERROR_RULE[task]
        for checkpoint in checkpoints(folder, args.every, args.fine_every, args.fine_until):
            out = work / f"{folder.name}-{args.sample_space}-{args.seed}-{checkpoint.stem}"
            result = evaluate(task, args, out, "ppo", "--param", f"ppo.model_path={checkpoint.resolve()}")
            result = result[result.controller == "ppo"].set_index("sample")
            ratio = result["cost_hjb"] / optimum.loc[result.index, "cost_hjb"]
            rows.append(
                {
                    "task": task,
                    "run": str(folder),
                    "timesteps": int(checkpoint.stem),
                    "median_ratio": float(ratio.median()),
                    "p90_ratio": float(ratio.quantile(0.9)),
                    "success": float(result["success"].astype(bool).mean()),
                    "on_target": float((result[column] <= limit).mean()),
                    "limit_crossed": float((result["joint_limit_margin"] < 0).mean()),
                    "file": str(checkpoint),
                }
            )
            print(
                f"{task} {rows[-1]['timesteps']:>9d} steps: median ratio {rows[-1]['median_ratio']:.3f}, "
                f"success {100 * rows[-1]['success']:.0f} %, on target {100 * rows[-1]['on_target']:.0f} %, "
                f"limit crossed {100 * rows[-1]['limit_crossed']:.0f} %",
                flush=True,
            )
    table = pd.DataFrame(rows)
    table["chosen"] = False
    for task, group in table.groupby("task"):
        eligible = group[group.success >= group.success.max() - args.success_slack - 1e-9]
        table.loc[eligible.median_ratio.idxmin(), "chosen"] = True
    print(table[table.chosen][["task", "timesteps", "median_ratio", "success", "file"]].to_string(index=False))
    if args.table:
        table.to_csv(args.table, index=False)
    plot(table, periodic, Path(args.out), args, baselines)


def plot(
    table: pd.DataFrame,
    periodic: dict[str, pd.DataFrame],
    out: Path,
    args: argparse.Namespace,
    baselines: dict[str, tuple[float, float]],
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colours = {"reach": "tab:blue", "track": "tab:orange"}
    for task, rows in table.groupby("task"):
        rows = rows.sort_values("timesteps")
        colour = colours.get(task, "k")
        axes[0].plot(rows.timesteps / 1e6, rows.median_ratio, "o-", color=colour, label=task)
        chosen = rows[rows.chosen]
        axes[0].plot(chosen.timesteps / 1e6, chosen.median_ratio, "*", ms=16, color=colour, mec="k")
        axes[1].plot(rows.timesteps / 1e6, 100 * rows.success, "o-", color=colour, label=f"{task}: success (evaluator)")
        axes[1].plot(
            rows.timesteps / 1e6,
            100 * rows.on_target,
            "s--",
            color=colour,
            mfc="none",
            label=f"{task}: on target (error rule alone)",
        )
        if task in baselines:
            axes[0].axhline(baselines[task][0], color=colour, ls=":", lw=1.2, label=f"{task}: {args.baseline}")
            axes[1].axhline(100 * baselines[task][1], color=colour, ls=":", lw=1.2)
        runs = periodic.get(task)
        if runs is not None and not runs.empty:
            axes[1].plot(
                runs.timesteps / 1e6,
                100 * runs.success_rate,
                ":",
                color=colour,
                alpha=0.6,
                label=f"{task}: periodic evaluation (10 episodes)",
            )
    axes[0].axhline(1.5, color="grey", ls="--", lw=1)
    axes[0].text(0.02, 1.53, "goal ≤ 1.5", color="grey", va="bottom", transform=axes[0].get_yaxis_transform())
    axes[0].set_yscale("log")
    axes[0].set_ylim(1.0, 4.0)  # the first checkpoints (ratio 8 to 130) are above the frame
    ticks = [1, 1.2, 1.5, 2, 3, 4]
    axes[0].set_yticks(ticks)
    axes[0].set_yticklabels([f"{t:g}" for t in ticks])
    axes[0].minorticks_off()
    axes[0].set_ylabel("median HJB cost / optimum")
    axes[1].axhline(95, color="grey", ls="--", lw=1)
    low = args.success_floor
    axes[1].text(
        0.02,
        95 + 0.01 * (102 - low),
        "dashed: goal ≥ 95 %",
        color="grey",
        va="bottom",
        transform=axes[1].get_yaxis_transform(),
    )
    axes[1].set_ylabel("% of validation samples")
    axes[1].set_ylim(low, 102)
    axes[1].legend(fontsize=7, loc="lower right")
    for ax in axes:
        ax.set_xlabel("env steps (millions)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(
        f"PPO trained on the whole workspace: checkpoints on {args.samples} {args.sample_space} validation "
        f"samples of seed {args.seed} (HJB cost, Q = 4I; ★ chosen)",
        fontsize=10,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
