"""The report of ``learners.py``: its jobs' scores aggregated over seeds with rliable.

    python docs/scripts/learners.py --out runs/learners --report-only

Per run (a learner, a task, a training seed), from its ``scores.csv`` (one row per held-out sample): the success
rate, and the median over all the samples of cost / reference (a failed sample counts at the cost it actually had).
Across the runs of a learner, per task and over both tasks: rliable's interquartile mean (IQM, the 25 % trimmed
mean over runs × tasks; of three runs of one task it trims nothing, so it is their mean) with a 95 %
stratified-bootstrap percentile interval (runs resampled within each task). The performance profile counts
episodes, with a 95 % stratified-bootstrap band over the runs: solid, the fraction of a learner's (run, sample)
episodes at a cost ≤ τ × the reference's, each at the cost it had (the table's measure); dashed, those that also
succeed (a failure is never within τ, Dolan and Moré's convention); the legend gives the success rate.

Writes ``OUT/scores.csv`` (every sample), ``OUT/runs.csv``, ``OUT/summary.csv``, ``OUT/table.md`` and the figure;
``--data DIR`` also writes the four files to DIR, with ``source.json`` (the command and the commit).
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from rliable import metrics  # its metrics need numpy and scipy only (rliable.library, arch's bootstrap, is not used)
from scipy.stats import trim_mean

#: Bootstrap resamples of the intervals, and the seed of their generator (the report is reproducible).
REPS = 20_000
BOOTSTRAP_SEED = 0
#: The τ of the performance profile: cost ≤ τ × the reference's, 1 to 10⁴ on a log grid.
TAUS = np.geomspace(1.0, 1e4, 161)
#: The rows of the summary: each task, and both together.
BOTH = "both"
COLOURS = {"ppo": "tab:blue", "sac": "tab:orange", "td3": "tab:green", "tqc": "tab:red"}


#: The error the success rule of each task reads (the evaluator's results): reach, the final error (≤ 1 mm);
#: track, the mean error over the second half (≤ 5 mm).
ERRORS = {"reach": "final_error", "track": "mean_error_2nd_half"}


def with_errors(scores: pd.DataFrame, folder: Path) -> pd.DataFrame:
    """A job's scores with ``error_m``, the error its task's success rule reads, from the evaluator's results of the
    job (``FOLDER/evaluation/results.csv``), where they are."""
    path = folder / "evaluation" / "results.csv"
    if not path.exists():
        return scores
    results = pd.read_csv(path)
    learned = results[results.controller != "optimal"].set_index("sample")
    column = ERRORS[str(scores.task.iloc[0])]
    return scores.assign(error_m=learned.loc[scores["sample"], column].to_numpy())


def read_scores(folders: Sequence[Path]) -> pd.DataFrame:
    """The ``scores.csv`` of every folder that has one, in one table (with ``error_m``, :func:`with_errors`)."""
    frames = [
        with_errors(pd.read_csv(folder / "scores.csv"), folder)
        for folder in folders
        if (folder / "scores.csv").exists()
    ]
    if not frames:
        raise FileNotFoundError(f"no scores.csv in {len(folders)} job folders (run the jobs first)")
    return pd.concat(frames, ignore_index=True)


def run_table(scores: pd.DataFrame, out: Path) -> pd.DataFrame:
    """One row per run: its success rate, median and mean cost / reference, and its training's budget and time."""
    runs = (
        scores.groupby(["learner", "task", "seed"], sort=False)
        .agg(
            samples=("ratio", "size"),
            success=("success", "mean"),
            median_ratio=("ratio", "median"),
            mean_ratio=("ratio", "mean"),
            reference_success=("reference_success", "mean"),
            median_error_m=("error_m", "median"),
        )
        .reset_index()
    )
    timing = []
    for row in runs.itertuples():
        path = out / f"{row.learner}_{row.task}_{row.seed}" / "train.json"
        record = json.loads(path.read_text()) if path.exists() else {}
        timing.append({key: record.get(key, np.nan) for key in ("steps", "train_wall_s", "train_cpu_s")})
    return pd.concat([runs, pd.DataFrame(timing)], axis=1)


def iqm(scores: np.ndarray) -> float:
    """rliable's IQM of a (runs × tasks) matrix: the 25 % trimmed mean of all its entries."""
    return float(metrics.aggregate_iqm(scores))


def iqm_rows(samples: np.ndarray) -> np.ndarray:
    """:func:`iqm` of each resample at once: ``samples`` (reps × runs × tasks) → (reps,)."""
    return np.asarray(trim_mean(samples.reshape(len(samples), -1), 0.25, axis=1), dtype=float)


def stratified_bootstrap(
    scores: np.ndarray, statistic: Callable[[np.ndarray], np.ndarray], reps: int = REPS, seed: int = BOOTSTRAP_SEED
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The statistic of a (runs × tasks) matrix and its 95 % stratified-bootstrap percentile interval.

    rliable's resampling (``rliable.library.StratifiedBootstrap``, task_bootstrap off): every entry of a resample is
    a run drawn with replacement from the same task's column. Done here with a seeded generator, because rliable
    1.2's ``get_interval_estimates`` passes ``random_state`` to arch, which arch 8 no longer takes (and arch 7 does
    not import with pandas 3).

    Args:
        statistic: Maps a stack of resamples (reps × runs × tasks) to their values (reps × k).

    Returns:
        ``(point, low, high)``, each of size k.
    """
    rng = np.random.default_rng(seed)
    runs, tasks = scores.shape
    point = statistic(scores[None])[0]
    values = np.empty((reps, len(point)))
    chunk = 1000  # resamples built at once (memory: chunk × runs × tasks)
    for start in range(0, reps, chunk):
        count = min(chunk, reps - start)
        draws = rng.integers(0, runs, size=(count, runs, tasks))
        values[start : start + count] = statistic(scores[draws, np.arange(tasks)])
    low, high = np.percentile(values, [2.5, 97.5], axis=0)
    return point, low, high


def matrix(runs: pd.DataFrame, learner: str, tasks: Sequence[str], column: str) -> np.ndarray:
    """``column`` of ``learner``'s runs as a (seeds × tasks) matrix (the seeds every task has)."""
    rows = runs[(runs.learner == learner) & runs.task.isin(tasks)]
    table = rows.pivot(index="seed", columns="task", values=column).reindex(columns=list(tasks)).dropna()
    return table.to_numpy(dtype=float)


def summary(runs: pd.DataFrame, reps: int = REPS) -> pd.DataFrame:
    """Per task (and over both) and learner: the runs, and the IQM with its interval of success and median ratio."""
    tasks = list(dict.fromkeys(runs.task))
    rows = []
    for group in [[task] for task in tasks] + ([tasks] if len(tasks) > 1 else []):
        for learner in dict.fromkeys(runs.learner):
            if not matrix(runs, learner, group, "success").size:  # no finished run of every task of the group yet
                continue
            row: dict[str, Any] = {"task": group[0] if len(group) == 1 else BOTH, "learner": learner}
            for column in ("success", "median_ratio"):
                scores = matrix(runs, learner, group, column)
                point, low, high = stratified_bootstrap(scores, lambda x: iqm_rows(x)[:, None], reps)
                row["runs"] = scores.shape[0]
                row[f"{column}_iqm"], row[f"{column}_low"], row[f"{column}_high"] = point[0], low[0], high[0]
            if "median_error_m" in runs and len(group) == 1:  # the tasks' errors are different measures
                row["median_error_m_iqm"] = iqm(matrix(runs, learner, group, "median_error_m"))
            rows.append(row)
    return pd.DataFrame(rows)


def episode_ratios(scores: pd.DataFrame, learner: str, task: str, failures: str = "cost") -> np.ndarray:
    """(seeds × samples): cost / reference per episode; a failed episode at its cost (``failures="cost"``) or
    ``inf`` (``"never"``: never within any τ)."""
    rows = scores[(scores.learner == learner) & (scores.task == task)]
    ratios = rows.ratio if failures == "cost" else rows.ratio.where(rows.success.astype(bool), np.inf)
    table = rows.assign(value=ratios).pivot(index="seed", columns="sample", values="value").dropna()
    return table.to_numpy(dtype=float)


def within(samples: np.ndarray, taus: np.ndarray = TAUS) -> np.ndarray:
    """The profile of each resample: (reps × runs × samples) ratios → (reps × τ) fractions ≤ τ."""
    flat = np.sort(samples.reshape(len(samples), -1), axis=1)
    counts = np.stack([np.searchsorted(row, taus, side="right") for row in flat])
    return np.asarray(counts / flat.shape[1], dtype=float)


#: A profile: per task, learner and way of counting failures (``"cost"``, ``"never"``), the fraction and its band.
Profiles = dict[str, dict[str, dict[str, tuple[np.ndarray, ...]]]]


def profiles(scores: pd.DataFrame, reps: int = REPS // 10) -> Profiles:
    """Per task and learner: the fraction of episodes within τ × the reference, and its bootstrap band, with the
    failures at their cost and with the failures never within τ."""
    return {
        task: {
            learner: {
                failures: stratified_bootstrap(episode_ratios(scores, learner, task, failures), within, reps)
                for failures in ("cost", "never")
            }
            for learner in dict.fromkeys(scores.learner)
            if ((scores.learner == learner) & (scores.task == task)).any()
        }
        for task in dict.fromkeys(scores.task)
    }


def draw(curves: Profiles, success: dict[tuple[str, str], float], path: Path, note: str) -> None:
    """The performance profile, one panel per task."""
    # matplotlib without a display
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(curves), figsize=(5.2 * len(curves), 3.8), sharey=True, squeeze=False)
    for ax, (task, learners) in zip(axes[0], curves.items(), strict=True):
        for learner, kinds in learners.items():
            colour = COLOURS.get(learner)
            label = f"{learner.upper()} ({100 * success[task, learner]:.0f} % succeed)"
            for failures, style in (("cost", "-"), ("never", "--")):
                fraction, low, high = kinds[failures]
                ax.plot(
                    TAUS, fraction, style, color=colour, label=label if style == "-" else None, drawstyle="steps-post"
                )
                ax.fill_between(TAUS, low, high, color=colour, alpha=0.15, step="post")
        ax.set_xscale("log")
        ax.set_xlim(TAUS[0], TAUS[-1])
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(task)
        ax.set_xlabel("τ: cost ≤ τ × the reference's (HJB cost, Q = 4·I)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(loc="upper left", fontsize=8)
    axes[0][0].set_ylabel("fraction of episodes within τ")
    fig.suptitle(note, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cell(point: float, low: float, high: float, percent: bool = False) -> str:
    if percent:
        return f"{100 * point:.0f} % [{100 * low:.0f}, {100 * high:.0f}]"
    digits = 3 if point < 10 else 1 if point < 100 else 0
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def markdown(table: pd.DataFrame) -> str:
    """The summary as the Markdown table of docs/rl.md."""
    errors = "median_error_m_iqm" in table
    lines = [
        "| task | learner | seeds | success, IQM [95 % CI] | median cost / reference, IQM [95 % CI] |"
        + (" median error, IQM |" if errors else ""),
        "|---|---|---|---|---|" + ("---|" if errors else ""),
    ]
    for row in table.itertuples():
        success = _cell(row.success_iqm, row.success_low, row.success_high, percent=True)
        ratio = _cell(row.median_ratio_iqm, row.median_ratio_low, row.median_ratio_high)
        error = (
            ""
            if not errors
            else " – |"
            if np.isnan(row.median_error_m_iqm)
            else f" {1000 * row.median_error_m_iqm:.0f} mm |"
        )
        lines.append(f"| {row.task} | {row.learner.upper()} | {row.runs} | {success} | {ratio} |{error}")
    return "\n".join(lines) + "\n"


def report(out: Path, folders: Sequence[Path], figure: Path | None = None, data: Path | None = None) -> int:
    """Aggregate the finished jobs among ``folders`` into ``out`` (and ``data``, with the command that made them, and
    the figure); print the table."""
    scores = read_scores(folders)
    runs = run_table(scores, out)
    table = summary(runs)
    text = markdown(table)
    for folder in [out] + ([data] if data is not None else []):
        folder.mkdir(parents=True, exist_ok=True)
        scores.to_csv(folder / "scores.csv", index=False, float_format="%.6g")
        runs.to_csv(folder / "runs.csv", index=False, float_format="%.6g")
        table.to_csv(folder / "summary.csv", index=False, float_format="%.6g")
        (folder / "table.md").write_text(text)
    if data is not None:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=False).stdout
        source = {"command": "python " + " ".join(sys.argv), "commit": commit.strip()}
        (data / "source.json").write_text(json.dumps(source, indent=1) + "\n")
    steps = ", ".join(f"{int(s):,}" for s in sorted(runs.steps.dropna().unique()))
    note = (
        f"{len(runs)} runs, {steps} steps each; {int(runs.samples.max())} held-out samples per run and task.\n"
        "Solid: every episode at its cost; dashed: succeeded episodes only. Bands: 95 % stratified bootstrap over seeds"
    )
    success = scores.groupby(["task", "learner"]).success.mean().to_dict()
    draw(profiles(scores), success, figure or out / "profile.png", note)
    print(text, end="")
    return 0
