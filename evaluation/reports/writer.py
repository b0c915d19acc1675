"""The reports of a run: ``summary.md`` (Table I's layout and the details behind it) and the box plots.

:func:`write_reports` writes ``summary.csv`` (the table of :mod:`snac_gym.evaluation.reports.summary`),
``summary.md`` (:func:`summary_markdown`, one helper per section) and ``cost_boxplot.png``
(:func:`plot_cost_boxes`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.reference.optimum import OPTIMAL, OWN_STARTS
from snac_gym.evaluation.reports.summary import CONVENTION_COLUMNS, controller_label, summarise

from snac_gym.common.outputs import write_text_whole, write_whole
from snac_gym.control.trajopt import FTOL, GAP_RTOL
from snac_gym.tasks import get_task


def optimality_markdown(summary: pd.DataFrame, results: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """The summary's optimality-gap section (empty without the ``optimal`` reference)."""
    if OPTIMAL not in set(summary["controller"]):
        return []
    lines = [
        "",
        "## Optimality gap",
        "",
        (
            f"`{OPTIMAL}`: per sample, the numerical optimum of the same cost over the same horizon and Δt, "
            "inside the same joint position and velocity limits the success rule counts (unless the run says "
            "`--reference-limits velocity`), **an open-loop reference computed with knowledge of the whole "
            "reference** (not a controller; no effort knob). It is a function of the sample alone: Gauss–Newton in "
            "the joint angles, a primal-dual interior point where a limit binds, started from rest and from "
            f"{len(OWN_STARTS)} feedback rollouts of its own at fixed settings ({', '.join(n for n, _ in OWN_STARTS)}; "
            "never the run's controllers; a start that reaches a known optimum's basin is not solved again), the "
            "best local optimum kept (a local optimum: a basin no start leads into is not searched); "
            f"stopped at a step predicting a gain ≤ {GAP_RTOL:g}·V or a relative decrease ≤ {FTOL:g} "
            "(docs/optimal.md). Ratio = a controller's cost / the optimum on the same sample. A rollout below the "
            "optimum that keeps the limits would be a failure of the reference; one that crosses a limit is "
            "counted apart (the optimum does not cross them)."
        ),
        "",
        "| Task | Controller | V/N | mean ratio | median ratio | V/N ratio | below the optimum, inside the limits "
        "| below it, crossing a limit |",
        "|---|---|---|---|---|---|---|---|",
    ]
    violations: list[tuple[str, str, int]] = []
    for t in tasks:
        p = f"{t}_"
        if p + "ratio_to_optimal_mean" not in summary:
            continue
        for _, row in summary.iterrows():
            below = int(row[p + "below_optimal"]) if not pd.isna(row[p + "below_optimal"]) else 0
            crossing = row.get(p + "below_optimal_crossing", 0)
            crossing = 0 if pd.isna(crossing) else int(crossing)
            if below:
                violations.append((t, row["controller"], below))
            lines.append(
                f"| {t} | {row['label']} | {_general_number(row[p + 'cost'])} | "
                f"{_general_number(row[p + 'ratio_to_optimal_mean'])} | "
                f"{_general_number(row[p + 'ratio_to_optimal_median'])} | "
                f"{_general_number(row[p + 'ratio_of_means_to_optimal'])} | {below} | {crossing} |"
            )
    lines.append("")
    return lines + _solver_lines(summary, tasks) + _below_optimum_lines(results, violations)


def _solver_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """One paragraph per task on how the optimum's solver did."""
    optimal_row = summary[summary["controller"] == OPTIMAL].iloc[0]
    lines = []
    for t in tasks:
        p = f"{t}_"
        if p + "optimal_converged_fraction" in summary:
            lines.append(
                f"Solver, {t}: converged on {optimal_row[p + 'optimal_converged_fraction']:.1%} of the samples, "
                f"largest final gradient {optimal_row[p + 'optimal_gradient_max']:.3g} "
                f"(estimated V − V* ≤ {optimal_row[p + 'optimal_gap_estimate_max']:.2g}), "
                f"median {optimal_row[p + 'optimal_iterations_median']:.0f} iterations, "
                f"on {int(optimal_row[p + 'optimal_bounded'])} samples the unconstrained optimum broke a limit "
                "(solved by the interior point), "
                f"{optimal_row[p + 'optimal_solve_time_mean']:.3f} s per sample (one worker)"
                + _bound_text(optimal_row, p)
                + "."
            )
            lines.append("")
    return lines


def _bound_text(row: pd.Series, p: str) -> str:
    """The optimum's gap to the certified lower bound, where the run has one."""
    median = row.get(p + "optimal_bound_ratio_median", math.nan)
    if pd.isna(median):
        return ""
    return (f"; optimum / certified lower bound: median {median:.3g}, "
            f"95th percentile {row[p + 'optimal_bound_ratio_p95']:.3g} (docs/lower-bounds.md)")  # fmt: skip


def _below_optimum_lines(results: pd.DataFrame, violations: Sequence[tuple[str, str, int]]) -> list[str]:
    """A warning naming the samples where a controller that keeps the limits beat the optimum (a failure of the
    reference)."""
    if not violations:
        return ["No controller that keeps the limits has a cost below the optimum on any sample.", ""]
    below = results[results["below_optimal"].astype(bool) & (results["joint_limit_margin"] >= 0.0)]
    listed = ", ".join(f"{r.task} #{r.sample} ({r.controller})" for r in below.head(20).itertuples())
    return [
        "**Warning: the optimum is not a lower bound everywhere.** The reference missed a better basin or "
        "did not converge on these samples (a controller that keeps the limits costs less): "
        + ", ".join(f"{c} on {n} {t} sample(s)" for t, c, n in violations)
        + f". First ones: {listed}.",
        "",
    ]


def _number(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return f"{value:.{digits}f}"


def _general_number(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return f"{value:.4g}"


def _paired_cell(row: pd.Series, prefix: str) -> list[str]:
    ratio = row.get(prefix + "median_ratio", math.nan)
    if pd.isna(ratio):
        return ["—", "—", "—"]
    p_value = row.get(prefix + "wilcoxon_p", math.nan)
    return [
        f"{ratio:.4g} [{row[prefix + 'ci_low']:.4g}, {row[prefix + 'ci_high']:.4g}]",
        f"{100 * row[prefix + 'fraction_better']:.1f} %",
        "—" if pd.isna(p_value) else f"{p_value:.2g}",
    ]


def paired_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """The paired comparison per task: every controller against the best ranked one and the optimum."""
    lines = [
        "",
        "## Paired comparison",
        "",
        "Every controller ran on the same samples, so each is compared with the best ranked controller and "
        "with the optimum sample by sample: the median over samples of the cost ratio (this controller / the "
        "other on the same sample) with a bootstrap 95 % confidence interval, the share of samples where this "
        "controller costs less, and the two-sided Wilcoxon signed-rank p-value of the paired differences. "
        "Medians of ratios are not moved by the few samples whose cost explodes; means are (docs/evaluation.md).",
    ]
    for t in tasks:
        best = summary.get(f"{t}_vs_best")
        best_name = best.dropna().iloc[0] if best is not None and best.notna().any() else None
        header = f"vs the best ({controller_label(best_name)})" if best_name else "vs the best (none ranked)"
        lines += [
            "",
            f"**{get_task(t).label}**",
            "",
            f"| Controller | {header}: median ratio [95 % CI] | cheaper on | p "
            "| vs the optimum: median ratio [95 % CI] "
            "| cheaper on | p |",
            "|---|---|---|---|---|---|---|",
        ]
        for _, row in summary.iterrows():
            if row["controller"] == OPTIMAL or pd.isna(row.get(f"{t}_cost", math.nan)):
                continue
            cells = _paired_cell(row, f"{t}_vs_best_") + _paired_cell(row, f"{t}_vs_optimal_")
            fails = "" if row.get(f"{t}_qualified", True) else " (**fails**)"  # cheap, but not doing the task
            lines.append(f"| {controller_label(row['controller'])}{fails} | " + " | ".join(cells) + " |")
    return lines


def summary_markdown(
    summary: pd.DataFrame,
    config: Any,
    efforts: Sequence[Any],
    skipped: dict[str, str],
    effort_statistic: str,
    timings: dict[str, float] | None = None,
    executor: str = "",
    results: pd.DataFrame | None = None,
) -> str:
    """``summary.md``: Table I's layout, the details behind it, the effort matching and the plot."""
    tasks = [t for t in config.tasks if f"{t}_cost" in summary]
    lines = _introduction_lines(summary, config, tasks, effort_statistic)
    lines += _calibration_source_lines(efforts)  # before the first table: the command prints up to its first "##"
    lines += overview_lines(summary, tasks)
    lines += ["", "## Table I, in the paper's layout", ""]
    lines += _table_one_lines(summary, tasks)
    lines += _convention_lines(summary, tasks, config.convention.q_scale)
    lines += paired_lines(summary, tasks)
    lines += _critic_lines(summary, tasks)
    for t in tasks:
        lines += _task_detail_lines(summary, t)
    if results is not None:
        lines += optimality_markdown(summary, results, tasks)
    lines += _effort_lines(summary, config, efforts, effort_statistic)
    lines += _closing_lines(skipped, timings, executor, getattr(config, "plots", True))
    return "\n".join(lines)


def _effort_set_text(config: Any) -> str:
    size = getattr(config, "effort_set_size", None)
    if size is None:
        return ""
    return (
        f", on the first {size} samples of the seed (`--effort-samples`; the efforts in the effort table are "
        "theirs), so that the matched knobs do not depend on how many samples are evaluated"
    )


def _introduction_lines(summary: pd.DataFrame, config: Any, tasks: Sequence[str], effort_statistic: str) -> list[str]:
    """The title, what was run and scored, and what success and accuracy mean."""
    n_text = ", ".join(f"{int(summary[f'{t}_n'].max())} {get_task(t).label.lower()} samples" for t in tasks)
    horizons = ", ".join(f"{t} {config.steps(t)} steps ({config.steps(t) * config.dt:g} s)" for t in tasks)
    threshold = getattr(config, "success_threshold", 0.95)
    return [
        "# Trajectory cost V/N (Table I of the paper)",
        "",
        f"Engine `{config.engine}`, {n_text}, seed {config.seed}, Δt = {config.dt:g} s, horizons: {horizons}. "
        f"{config.convention.describe()}; V/N is the mean over samples, "
        "± its standard deviation, with the 95 % bootstrap percentile interval of the mean (seeded; the paired "
        "medians below are the comparison one heavy-tailed sample cannot move). "
        + (
            "Equal effort: " + effort_statistic + " matched (table below)" + _effort_set_text(config) + "."
            if config.match_effort
            else "No effort matching (each controller at its own settings)."
        ),
        "",
        (
            "Success: " + "; ".join(f"{t}: {get_task(t).success_text()}" for t in tasks) + ". "
            f"Only controllers with a success rate of at least {threshold:.0%} on a "
            "task are ranked there (rank, ratio to the best, ratio to SNAC); the others are marked **fails** and are "
            "never ranked, whatever their cost. Accuracy: median final error (reach) or median over samples of the "
            "median error over the second half (track)."
        ),
        "",
    ]


#: The overview's columns (at most 8: a table a person reads).
OVERVIEW_COLUMNS = (
    "Controller",
    "V/N [95 % CI]",
    "success",
    "accuracy (mm)",
    "rank (ratio to best)",
    "cost / optimum (median)",
    "vs the best: median ratio [95 % CI]",
    "cheaper than the best on",
)


def overview_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """The summary's first table, one per task: cost beside accuracy and the paired comparisons. A controller
    below the success threshold is marked **fails** and not ranked, whatever its cost."""
    lines: list[str] = []
    for t in tasks:
        p = f"{t}_"
        best = summary.get(f"{t}_vs_best")
        best_name = best.dropna().iloc[0] if best is not None and best.notna().any() else None
        lines += [
            f"**{get_task(t).label}** ({int(summary[p + 'n'].max())} samples; the best ranked: "
            f"{controller_label(best_name) if best_name else 'none'})",
            "",
            "| " + " | ".join(OVERVIEW_COLUMNS) + " |",
            "|" + "---|" * len(OVERVIEW_COLUMNS),
        ]
        for _, row in summary.iterrows():
            if pd.isna(row.get(p + "cost", math.nan)):
                continue
            accuracy = row[f"{p}{get_task(t).accuracy_measure}_median"] * 1e3
            versus, cheaper = _paired_cell(row, p + "vs_best_")[:2]
            if row["controller"] == OPTIMAL:
                standing, to_optimum, versus, cheaper = "reference", "1", "—", "—"
            else:
                qualified = bool(row.get(p + "qualified", False))
                standing = f"{int(row[p + 'rank'])} ({_number(row[p + 'ratio_to_best'])})" if qualified else "**fails**"
                to_optimum = _general_number(row.get(p + "vs_optimal_median_ratio", math.nan))
                if not qualified:  # cheaper than the best is no merit in a controller that does not do the task
                    versus, cheaper = "— (fails the task)", "—"
            if row["controller"] == best_name:
                versus, cheaper = "(the best)", "—"
            lines.append("| " + " | ".join([
                row["label"],
                f"{_number(row[p + 'cost'])} "
                f"[{_number(row[p + 'cost_ci95_low'])}, {_number(row[p + 'cost_ci95_high'])}]",
                f"{row[p + 'success_rate']:.1%}", _number(accuracy, 3), standing, to_optimum, versus, cheaper,
            ]) + " |")  # fmt: skip
        lines.append("")
    return lines


def _table_one_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """Table I's layout: per task V/N, its interval, the share of it that is the first command's jump
    (where the cost has one), the paper's value, success, accuracy and standing."""
    jump = all(f"{t}_first_jump_percent" in summary for t in tasks)
    header = "| Controller |" + "".join(
        f" {get_task(t).label} V/N (ours) | 95 % CI |"
        + (" jump share |" if jump else "")
        + " paper | success | accuracy (mm) | rank (ratio to best) | ratio to SNAC (ours / paper) |"
        for t in tasks
    )
    lines = [header, "|---|" + ("---|" * (8 if jump else 7)) * len(tasks)]
    for _, row in summary.iterrows():
        cells = [row["label"]]
        for t in tasks:
            task_cells = _table_one_cells(row, t)
            if jump:
                share = row[f"{t}_first_jump_percent"]
                task_cells.insert(2, "—" if pd.isna(share) else f"{share:.1f} %")
            cells += task_cells
        lines.append("| " + " | ".join(cells) + " |")
    if jump:
        lines += [
            "",
            "Jump share: the part of V/N that is the first step's jump from rest, ‖u₀‖²_R/Δt (u₋₁ = 0, Δt = "
            "the control period; Σ over samples of that term / Σ V). Where it is near 100 % the ranking is "
            "that of the size of the first command; V/N without it (u₋₁ = u₀) is in the next table.",
        ]
    return lines


def _table_one_cells(row: pd.Series, task: str) -> list[str]:
    """One controller's cells of ``task`` in Table I's layout."""
    p = f"{task}_"
    accuracy = row[f"{p}{get_task(task).accuracy_measure}_median"] * 1e3
    if row["controller"] == OPTIMAL:
        standing = "reference"
    elif bool(row.get(p + "qualified", False)):
        standing = f"{int(row[p + 'rank'])} ({_number(row[p + 'ratio_to_best'])})"
    else:
        standing = "**fails**"
    return [
        f"{_number(row[p + 'cost'])} ± {_number(row[p + 'cost_std'])}",
        f"[{_number(row[p + 'cost_ci95_low'])}, {_number(row[p + 'cost_ci95_high'])}]",
        _number(row[p + "paper"]),
        f"{row[p + 'success_rate']:.1%}",
        _number(accuracy, 3),
        standing,
        f"{_number(row[p + 'ratio_to_snac'])} / {_number(row[p + 'paper_ratio_to_snac'])}",
    ]


def _convention_lines(summary: pd.DataFrame, tasks: Sequence[str], q_scale: float) -> list[str]:
    """V/N of the same rollouts under each cost convention."""
    lines = [
        "",
        "## V/N under each cost convention",
        "",
        (
            "The same rollouts scored three ways: Table I's cost with the jump from rest (u₋₁ = 0), without it "
            "(u₋₁ = u₀), and the cost the controllers are derived for, Σ (eᵀQe + uᵀRu) Δt (no u̇ term). "
            f"Q = {'I' if q_scale == 1.0 else f'{q_scale:g}·I'}, R = I."
        ),
        "",
        "| Controller |" + "".join(f" {get_task(t).label}: u₋₁ = 0 | u₋₁ = u₀ | HJB cost |" for t in tasks),
        "|---|" + "---|---|---|" * len(tasks),
    ]
    for _, row in summary.iterrows():
        cells = [row["label"]]
        for t in tasks:
            cells += [_general_number(row.get(f"{t}_{c}", math.nan)) for c in CONVENTION_COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _critic_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """How far the critics are from optimal (only for controllers that report it)."""
    critics = [
        (t, row)
        for t in tasks
        for _, row in summary.iterrows()
        if not pd.isna(row.get(f"{t}_hjb_ratio_median", math.nan))
    ]
    if not critics:
        return []
    lines = [
        "",
        "## How far the critics are from optimal",
        "",
        (
            "Per rollout, the median over the run of the critic's HJB residual r/eᵀQe (0 for the optimal value "
            "function; sampled every 0.2 s) and, for regulation, ‖P̂ − P*(J)‖/‖P*‖ at the last step (P*: the "
            "frozen-Jacobian optimum); the medians over samples (docs/snac.md)."
        ),
        "",
        "| Task | Controller | median r/eᵀQe | median final critic error |",
        "|---|---|---|---|",
    ]
    for t, row in critics:
        lines.append(
            f"| {t} | {row['label']} | {_general_number(row[f'{t}_hjb_ratio_median'])} | "
            f"{_general_number(row.get(f'{t}_critic_error_final', math.nan))} |"
        )
    return lines


def _task_detail_lines(summary: pd.DataFrame, task: str) -> list[str]:
    """``task``'s cost terms and outcomes per controller."""
    p = f"{task}_"
    lines = [
        "",
        f"## {get_task(task).label} ({task}): cost terms and outcomes",
        "",
        (
            "| Controller | error term | effort term | smoothness term | of which first-step jump | success "
            "| median final error (mm) | median time to 1 mm (s) | settled | settle time median / p95 (s) "
            "| max ‖u‖∞ | max ‖u‖₂ |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, row in summary.iterrows():
        cells = [
            row["label"],
            _general_number(row[p + "cost_error"]),
            _general_number(row[p + "cost_effort"]),
            _general_number(row[p + "cost_smoothness"]),
            _general_number(row[p + "cost_smoothness_start"]),
            f"{row[p + 'success_rate']:.1%}",
            _number(row[p + "final_error_median"] * 1e3, 3),
            _number(row[p + "time_to_1mm_median"]),
            f"{row[p + 'settled_fraction']:.1%}",
            f"{_number(row[p + 'settle_time_median'])} / {_number(row[p + 'settle_time_p95'])}",
            _number(row[p + "max_abs_u"], 3),
            _number(row[p + "max_norm_u"], 3),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _calibration_source_lines(efforts: Sequence[Any]) -> list[str]:
    """Where the knobs came from when this run did not match them (the calibration cache)."""
    sources = sorted({e.calibrated_by for e in efforts if getattr(e, "calibrated_by", "")})
    if not sources:
        return []
    if any(source.startswith("the knobs shipped") for source in sources):
        return [
            "**The knobs were not matched by this run**: they are the knobs shipped with snac-gym for these "
            "default settings, matched on the same 1000-sample effort set (`python tools/ship_calibration.py`; the "
            "test suite recomputes them with the current code and fails when one moves; the efforts and targets "
            "below are that run's, on the effort set). `--recalibrate` matches them anew.",
            "",
        ]
    return [
        f"**The knobs were not matched by this run**: they come from the calibration cache, matched by "
        f"{' and '.join(sources)} on the same effort set, settings and code (the efforts and targets below are "
        "that run's, on the effort set). `--recalibrate` matches them anew.",
        "",
    ]


def _effort_lines(summary: pd.DataFrame, config: Any, efforts: Sequence[Any], effort_statistic: str) -> list[str]:
    """How each controller's effort was set, both effort statistics, and a warning for unmatched ones."""
    lines = [
        "",
        "## Control effort",
        "",
        f"Statistic: {effort_statistic}; tolerance {config.effort_tolerance:.0%} of the target."
        if config.match_effort
        else f"Statistic (not matched): {effort_statistic}.",
        "",
        *_calibration_source_lines(efforts),
        (
            "Both statistics of every controller's rollouts, whichever was matched: the maximum |u| over the "
            "sample set (rad/s) and the median over samples of each rollout's peak |u_j|/ū_j."
        ),
        "",
        (
            "| Task | Controller | role | knob | value | effort | target | max \\|u\\| over the set (rad/s) "
            "| median peak \\|u\\|/ū | passes | note |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    by_controller = summary.set_index("controller")
    for e in efforts:
        row = by_controller.loc[e.controller] if e.controller in by_controller.index else {}
        literal_max = row.get(f"{e.task}_max_abs_u", math.nan)
        median_peak = row.get(f"{e.task}_median_peak_limit_fraction", math.nan)
        lines.append(
            f"| {e.task} | {controller_label(e.controller)} | {e.role} | {e.knob or '—'} | "
            f"{_general_number(e.knob_value)} | {_number(e.effort, 4)} | {_number(e.target, 4)} | "
            f"{_number(literal_max, 4)} | {_number(median_peak, 4)} | {e.passes} | {e.note} |"
        )
    unmatched = [e for e in efforts if e.role == "unmatched"]
    if unmatched:
        lines += [
            "",
            "**Warning:** effort not matched for " + ", ".join(f"{e.controller} ({e.task})" for e in unmatched) + ".",
        ]
    return lines


def _closing_lines(
    skipped: dict[str, str], timings: dict[str, float] | None, executor: str, plots: bool = True
) -> list[str]:
    """The controllers left out, the wall time, and the box plot (when it is drawn)."""
    lines: list[str] = []
    if skipped:
        lines += ["", "Registered controllers left out:", ""] + [
            f"- `{name}`: {reason}" for name, reason in skipped.items()
        ]
    if timings:
        phases = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in timings.items() if name != "total")
        lines += [
            "",
            (
                f"Wall time {timings.get('total', math.nan):.1f} s on {executor} ({phases}); "
                "a resumed run counts only its own time."
            ),
        ]
    return lines + (["", "![Per-sample trajectory cost](cost_boxplot.png)", ""] if plots else [""])


def prefetch_report_modules() -> threading.Thread:
    """Import what the reports need (scipy.stats, matplotlib's pyplot: 1-2 s) in a daemon thread and return it.

    A run calls this when its last phase starts: its main process then mostly waits for the workers,
    and the reports, written by it alone after the last job, do not begin with these imports.
    """

    def load() -> None:
        try:
            import matplotlib  # in this thread, off the main one: the point of it

            matplotlib.use("Agg")
            import matplotlib.pyplot  # noqa: F401
            import scipy.stats  # noqa: F401
        except ImportError:  # the reports' own import says what is missing
            pass

    thread = threading.Thread(target=load, name="snac-gym report imports", daemon=True)
    thread.start()
    return thread


def plot_cost_boxes(
    results: pd.DataFrame, tasks: Sequence[str], controllers: Sequence[str], path: Path, success_threshold: float = 0.95
) -> Path:
    """Box plots of the per-sample cost, one panel per task, log scale; controllers that fail the
    task (success below ``success_threshold``) are drawn hatched and labelled so."""
    import matplotlib  # start-up time: each worker imports this module, never plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    fig, axes = plt.subplots(len(tasks), 1, figsize=(1.5 + 0.9 * len(controllers), 3.6 * len(tasks)), squeeze=False)
    for ax, task in zip(axes[:, 0], tasks, strict=True):
        data, labels, failing = [], [], []
        for controller in controllers:
            part = results.loc[(results["task"] == task) & (results["controller"] == controller)]
            if len(part):
                data.append(part["cost"].to_numpy())
                fails = controller != OPTIMAL and part["success"].mean() < success_threshold
                failing.append(fails)
                labels.append(("optimum" if controller == OPTIMAL else controller) + ("\n(fails)" if fails else ""))
        boxes = ax.boxplot(data, showmeans=True, patch_artist=True)
        for box, fails in zip(boxes["boxes"], failing, strict=True):
            box.set(facecolor="white", hatch="///" if fails else None, edgecolor="0.5" if fails else "black")
        ax.set_xticks(range(1, len(labels) + 1), labels)
        if all(np.all(d > 0) for d in data):
            ax.set_yscale("log")
        ax.set_title(f"{get_task(task).label} ({task}), ▲ mean")
        ax.set_ylabel("trajectory cost V per sample")
        ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    write_whole(path, lambda partial: fig.savefig(partial, dpi=110))
    plt.close(fig)
    return path


def write_reports(
    root: Path,
    results: pd.DataFrame,
    efforts: Sequence[Any],
    config: Any,
    skipped: dict[str, str],
    effort_statistic: str,
    timings: dict[str, float] | None = None,
    executor: str = "",
) -> pd.DataFrame:
    """Write ``summary.csv``, ``summary.md`` and ``cost_boxplot.png`` into ``root`` (the figure only
    where ``config.plots``; else one left by an earlier run of the folder is removed, not left stale)."""
    controllers = list(dict.fromkeys(results["controller"]))
    tasks = [t for t in config.tasks if (results["task"] == t).any()]
    threshold = getattr(config, "success_threshold", 0.95)
    summary = summarise(results, efforts, tasks, controllers, threshold, config.convention)
    write_whole(root / "summary.csv", lambda path: summary.to_csv(path, index=False, float_format="%.10g"))
    write_text_whole(
        root / "summary.md",
        summary_markdown(summary, config, efforts, skipped, effort_statistic, timings, executor, results),
    )
    if getattr(config, "plots", True):
        plot_cost_boxes(results, tasks, controllers, root / "cost_boxplot.png", threshold)
    else:
        (root / "cost_boxplot.png").unlink(missing_ok=True)
    return summary


__all__ = ["optimality_markdown", "plot_cost_boxes", "summary_markdown", "write_reports"]
