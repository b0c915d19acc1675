"""The tables of ``summary.md``: the overview, Table I in the paper's layout, the cost conventions, the paired
comparisons, the critic's optimality and each task's details, and how their numbers are written.

Part of :mod:`snac_gym.evaluation.reports.writer`, whose :func:`~snac_gym.evaluation.reports.writer.summary_markdown`
puts them in order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import pandas as pd
from snac_gym.evaluation.reference.optimum import OPTIMAL
from snac_gym.evaluation.reports.summary import CONVENTION_COLUMNS, controller_label

from snac_gym.tasks import get_task

__all__ = [
    "OVERVIEW_COLUMNS",
    "convention_lines",
    "critic_lines",
    "general_number",
    "number",
    "overview_lines",
    "paired_lines",
    "table_one_lines",
    "task_detail_lines",
]


def number(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return f"{value:.{digits}f}"


def general_number(value: Any) -> str:
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
                standing = f"{int(row[p + 'rank'])} ({number(row[p + 'ratio_to_best'])})" if qualified else "**fails**"
                to_optimum = general_number(row.get(p + "vs_optimal_median_ratio", math.nan))
                if not qualified:  # cheaper than the best is no merit in a controller that does not do the task
                    versus, cheaper = "— (fails the task)", "—"
            if row["controller"] == best_name:
                versus, cheaper = "(the best)", "—"
            lines.append("| " + " | ".join([
                row["label"],
                f"{number(row[p + 'cost'])} "
                f"[{number(row[p + 'cost_ci95_low'])}, {number(row[p + 'cost_ci95_high'])}]",
                f"{row[p + 'success_rate']:.1%}", number(accuracy, 3), standing, to_optimum, versus, cheaper,
            ]) + " |")  # fmt: skip
        lines.append("")
    return lines


def table_one_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
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
        standing = f"{int(row[p + 'rank'])} ({number(row[p + 'ratio_to_best'])})"
    else:
        standing = "**fails**"
    return [
        f"{number(row[p + 'cost'])} ± {number(row[p + 'cost_std'])}",
        f"[{number(row[p + 'cost_ci95_low'])}, {number(row[p + 'cost_ci95_high'])}]",
        number(row[p + "paper"]),
        f"{row[p + 'success_rate']:.1%}",
        number(accuracy, 3),
        standing,
        f"{number(row[p + 'ratio_to_snac'])} / {number(row[p + 'paper_ratio_to_snac'])}",
    ]


def convention_lines(summary: pd.DataFrame, tasks: Sequence[str], q_scale: float) -> list[str]:
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
            cells += [general_number(row.get(f"{t}_{c}", math.nan)) for c in CONVENTION_COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def critic_lines(summary: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
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
            f"| {t} | {row['label']} | {general_number(row[f'{t}_hjb_ratio_median'])} | "
            f"{general_number(row.get(f'{t}_critic_error_final', math.nan))} |"
        )
    return lines


def task_detail_lines(summary: pd.DataFrame, task: str) -> list[str]:
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
            general_number(row[p + "cost_error"]),
            general_number(row[p + "cost_effort"]),
            general_number(row[p + "cost_smoothness"]),
            general_number(row[p + "cost_smoothness_start"]),
            f"{row[p + 'success_rate']:.1%}",
            number(row[p + "final_error_median"] * 1e3, 3),
            number(row[p + "time_to_1mm_median"]),
            f"{row[p + 'settled_fraction']:.1%}",
            f"{number(row[p + 'settle_time_median'])} / {number(row[p + 'settle_time_p95'])}",
            number(row[p + "max_abs_u"], 3),
            number(row[p + "max_norm_u"], 3),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines
