"""The summary table of a run (``summary.csv``): per controller and task, V/N beside the paper's Table I.

The paper's values (Section V, "Quantitative Test Comparison": the normalised trajectory cost V/N
over 1000 regulation samples and 1000 feasible ellipses on a kinematic UR10 model, Q = I₃,
R = I₆, all controllers tuned to the same maximum control effort) are kept here with the row
and column labels the reports print.

``summary.csv`` has one row per controller and, per task (prefix ``reach_`` / ``track_``):
``cost`` (V/N, the mean over samples), ``cost_std``, ``cost_ci95_low``/``_high`` (the 95 % bootstrap
percentile interval of the mean, seeded: :func:`mean_confidence_interval`), ``n``, the mean of each cost term, ``paper``
(Table I), ``ratio_to_snac`` and ``paper_ratio_to_snac``, ``success_rate``, ``final_error_median``,
``time_to_1mm_median``, ``settled_fraction``, ``settle_time_median`` and ``settle_time_p95``
(order statistics; inf when too few rollouts settled within the horizon), the effort
statistic matched (``effort``), its knob (``effort_parameter``, ``effort_value``,
``effort_role``), both effort statistics whichever was matched (``max_abs_u``, the maximum |u|
over the set, and ``median_peak_limit_fraction``) and ``max_norm_u``.

Where the run's cost has the jump from rest (Table I's cost with u₋₁ = 0): ``first_jump_percent``,
the share of V/N that is the first command's jump ‖u₀‖²_R/Δt (Σ ``first_jump_cost`` / Σ ``cost``
over the samples, in %), and ``cost_without_first_jump``, V/N without it, i.e. with u₋₁ = u₀.

With the ``optimal`` reference (docs/optimal.md): ``ratio_to_optimal_mean`` (V/N's per-sample
counterpart: the mean over samples of cost / optimum), ``ratio_to_optimal_median``,
``ratio_of_means_to_optimal`` (V/N over the optimum's V/N), ``below_optimal_crossing`` (samples below the
optimum on a rollout that crosses a joint limit, which the optimum does not) and ``below_optimal`` (samples where
a rollout that keeps the limits beat the optimum: a failure of the reference); on the optimal row,
``optimal_converged_fraction``, ``optimal_gradient_max``, ``optimal_gap_estimate_max``, ``optimal_bounded``,
``optimal_iterations_median``, ``optimal_solve_time_mean`` (s per sample) and, with a certified lower
bound, ``optimal_bound_ratio_median`` and ``optimal_bound_ratio_p95`` (optimum / bound).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.reference.optimum import OPTIMAL, OPTIMAL_LABEL, OPTIMAL_VELOCITY_ONLY_LABEL
from snac_gym.evaluation.reports.paired import compare

from snac_gym.control.cost import CostConvention

#: Table I of the paper, rows in the paper's order: controller name in snac-gym → {task: V/N}.
PAPER_TABLE_I: dict[str, dict[str, float]] = {
    "rnn": {"reach": 49.74, "track": 14.39},
    "svf": {"reach": 48.32, "track": 32.21},
    "snac": {"reach": 5.78, "track": 3.30},
}

#: Row labels: the paper's for its controllers; DLS and PPO are not in the paper.
PAPER_LABELS: dict[str, str] = {
    "rnn": "RNN",
    "svf": "SVF",
    "snac": "Proposed (SNAC)",
    "dls": "DLS",
    "ppo": "PPO",
    OPTIMAL: OPTIMAL_LABEL,
}


def paper_value(controller: str, task: str) -> float | None:
    """Table I's V/N for ``controller`` on ``task``, or ``None`` if the paper has no such entry."""
    return PAPER_TABLE_I.get(controller, {}).get(task)


def _label(controller: str, results: pd.DataFrame) -> str:
    """:func:`controller_label`, except that the reference without the joint position limits says so."""
    if controller == OPTIMAL and "optimal_limits" in results:
        if (results.loc[results["controller"] == OPTIMAL, "optimal_limits"] == "velocity").any():
            return OPTIMAL_VELOCITY_ONLY_LABEL
    return controller_label(controller)


def controller_label(controller: str) -> str:
    """The row label of a controller: the paper's where it has one, else the registry name."""
    return PAPER_LABELS.get(controller, controller)


_TERMS = ("cost_error", "cost_effort", "cost_smoothness", "cost_smoothness_start")
#: V under the other conventions, whatever the run's (metrics columns).
CONVENTION_COLUMNS = ("cost_table1", "cost_table1_first", "cost_hjb")


#: Resamples of the bootstrap interval of V/N, and its seed: the same data give the same interval in every run.
BOOTSTRAP_RESAMPLES = 4000
BOOTSTRAP_SEED = 20120807


def mean_confidence_interval(
    values: np.ndarray, level: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> tuple[float, float, float, float]:
    """``(mean, std, low, high)``: the sample mean, its standard deviation (ddof 1) and the bootstrap percentile
    interval of the mean (``resamples`` resamples with replacement, seeded).

    A percentile interval is made of means of resamples of the data, so it never leaves the data's range: a
    cost cannot get a negative bound, as the normal approximation gave a heavy-tailed one (a mean driven by
    one sample far out). The interval is still that of a mean: for heavy tails the paired medians
    (:mod:`snac_gym.evaluation.reports.paired`) say more.
    """
    values = np.asarray(values, dtype=float)
    mean = float(values.mean())
    if values.size < 2 or not np.all(np.isfinite(values)):
        return mean, math.nan, math.nan, math.nan
    std = float(values.std(ddof=1))
    rng = np.random.default_rng(seed)
    means = np.empty(resamples)
    block = max(1, 2_000_000 // values.size)  # resamples per draw: ~16 MB of indices at most
    for start in range(0, resamples, block):
        stop = min(resamples, start + block)
        means[start:stop] = values[rng.integers(0, values.size, size=(stop - start, values.size))].mean(axis=1)
    low, high = np.quantile(means, [0.5 - level / 2, 0.5 + level / 2])
    return mean, std, float(low), float(high)


def summarise(
    results: pd.DataFrame,
    efforts: Sequence[Any],
    tasks: Sequence[str],
    controllers: Sequence[str],
    success_threshold: float = 0.95,
    convention: CostConvention | None = None,
) -> pd.DataFrame:
    """The summary table (see the module docstring) from the results and the effort records, scored
    under ``convention`` (default: Table I's cost with u₋₁ = 0).

    Only controllers whose success rate on a task reaches ``success_threshold`` are ranked there
    (``rank``, ``ratio_to_best``, ``ratio_to_snac``); the others have ``qualified`` False and NaN
    in those columns, so that a controller that fails the task is never shown as the cheapest.
    """
    effort_by_key = {(e.task, e.controller): e for e in efforts}
    # not from a run resumed from parts written before the column existed: the share would be silently low
    jumps = results.get("first_jump_cost", pd.Series([math.nan]))
    with_jump = (convention or CostConvention()).first_jump_weight > 0 and bool(jumps.notna().all())
    rows = []
    for controller in controllers:
        row: dict[str, Any] = {"controller": controller, "label": _label(controller, results)}
        for task in tasks:
            part = results[(results["task"] == task) & (results["controller"] == controller)]
            if part.empty:
                continue
            columns = {
                **_cost_columns(part),
                **(_first_jump_columns(part) if with_jump else {}),
                **_outcome_columns(part, controller, task),
                **_optimality_columns(part, controller),
                **_effort_columns(effort_by_key.get((task, controller))),
            }
            row.update({f"{task}_{name}": value for name, value in columns.items()})
        rows.append(row)
    summary = pd.DataFrame(rows)
    for task in tasks:
        if f"{task}_cost" in summary:
            _add_standing(summary, task, success_threshold)
            _add_paired(summary, results, task)
    return summary


#: What each controller is compared with, sample by sample (:mod:`snac_gym.evaluation.reports.paired`).
PAIRED_REFERENCES = ("best", "optimal")
_PAIRED_FIELDS = ("median_ratio", "ci_low", "ci_high", "fraction_better", "wilcoxon_p")


def _add_paired(summary: pd.DataFrame, results: pd.DataFrame, task: str) -> None:
    """Paired statistics of each controller against the best ranked one and against the optimum:
    ``{task}_vs_{best|optimal}_{median_ratio, ci_low, ci_high, fraction_better, wilcoxon_p}``."""
    p = f"{task}_"
    costs = results[results["task"] == task].pivot_table(index="sample", columns="controller", values="cost")
    ranked = summary.loc[summary[p + "rank"] == 1, "controller"]
    references = {"best": ranked.iloc[0] if len(ranked) else None, "optimal": OPTIMAL}
    for key, reference in references.items():
        for field in _PAIRED_FIELDS:
            summary[f"{p}vs_{key}_{field}"] = math.nan
        if reference is None or reference not in costs:
            continue
        summary[f"{p}vs_{key}"] = reference
        for i, controller in summary["controller"].items():
            if controller == reference or controller not in costs:
                continue
            comparison = compare(costs[controller].to_numpy(), costs[reference].to_numpy())
            for field in _PAIRED_FIELDS:
                summary.loc[i, f"{p}vs_{key}_{field}"] = getattr(comparison, field)


def _cost_columns(part: pd.DataFrame) -> dict[str, Any]:
    """V/N with its spread and interval, and the mean of every cost term and convention."""
    mean, std, low, high = mean_confidence_interval(part["cost"].to_numpy())
    columns: dict[str, Any] = {
        "cost": mean,
        "cost_std": std,
        "cost_ci95_low": low,
        "cost_ci95_high": high,
        "n": len(part),
    }
    for term in _TERMS + CONVENTION_COLUMNS:
        if term in part:
            columns[term] = float(part[term].mean())
    return columns


def _first_jump_columns(part: pd.DataFrame) -> dict[str, Any]:
    """The share of V/N that is the first command's jump from rest, and V/N without it (u₋₁ = u₀)."""
    total, jump = float(part["cost"].sum()), float(part["first_jump_cost"].sum())
    return {
        "first_jump_percent": 100.0 * jump / total if total > 0 else 0.0,
        "cost_without_first_jump": (total - jump) / len(part),
    }


def _outcome_columns(part: pd.DataFrame, controller: str, task: str) -> dict[str, Any]:
    """Accuracy, the critics' diagnostics, the paper's value, success, settling and peak effort."""
    columns: dict[str, Any] = {"median_error_2nd_half_median": float(part["median_error_2nd_half"].median())}
    for diagnostic in ("hjb_ratio_median", "critic_error_final"):
        values = part[diagnostic] if diagnostic in part else pd.Series(dtype=float)
        columns[diagnostic] = float(values.median()) if values.notna().any() else math.nan
    settle = part["settle_time"].fillna(np.inf).to_numpy()  # NaN: not settled within the horizon
    columns.update(
        {
            "paper": paper_value(controller, task),
            "success_rate": float(part["success"].mean()),
            "final_error_median": float(part["final_error"].median()),
            "time_to_1mm_median": float(part["time_to_1mm"].median()),
            "settled_fraction": float(np.isfinite(settle).mean()),
            "settle_time_median": float(np.quantile(settle, 0.5, method="inverted_cdf")),
            "settle_time_p95": float(np.quantile(settle, 0.95, method="inverted_cdf")),
            "max_abs_u": float(part["max_abs_u"].max()),
            "median_peak_limit_fraction": float(part["peak_limit_fraction"].median()),
            "max_norm_u": float(part["max_norm_u"].max()),
        }
    )
    return columns


def _optimality_columns(part: pd.DataFrame, controller: str) -> dict[str, Any]:
    """The ratios to the optimum (with the ``optimal`` reference) and, on its row, the solver's record."""
    columns: dict[str, Any] = {}
    if "ratio_to_optimal" in part:
        columns["ratio_to_optimal_mean"] = float(part["ratio_to_optimal"].mean())
        columns["ratio_to_optimal_median"] = float(part["ratio_to_optimal"].median())
        below = part["below_optimal"].astype(bool)
        crossing = (
            part["joint_limit_margin"] < 0.0 if "joint_limit_margin" in part else pd.Series(False, index=part.index)
        )
        # Below the optimum inside the limits would be a failure of the reference; across a limit it is not.
        columns["below_optimal"] = int((below & ~crossing).sum())
        columns["below_optimal_crossing"] = int((below & crossing).sum())
    if controller == OPTIMAL and "optimal_converged" in part:
        columns.update(
            {
                "optimal_converged_fraction": float(part["optimal_converged"].astype(bool).mean()),
                "optimal_gradient_max": float(part["optimal_gradient"].max()),
                "optimal_gap_estimate_max": float(part["optimal_gap_estimate"].max()),
                "optimal_bounded": int(part["optimal_bounded"].astype(bool).sum()),
                "optimal_iterations_median": float(part["optimal_iterations"].median()),
                "optimal_solve_time_mean": float(part["optimal_solve_time"].mean()),
            }
        )
        if "optimal_lower_bound" in part and part["optimal_lower_bound"].notna().any():
            ratio = part["cost"] / part["optimal_lower_bound"]
            columns["optimal_bound_ratio_median"] = float(ratio.median())
            columns["optimal_bound_ratio_p95"] = float(ratio.quantile(0.95))
    return columns


def _effort_columns(record: Any) -> dict[str, Any]:
    """How the effort was set (an :class:`~snac_gym.evaluation.effort.matching.EffortRecord`; none for ``optimal``)."""
    if record is None:
        return {}
    return {
        "effort": record.effort,
        "effort_target": record.target,
        "effort_role": record.role,
        "effort_parameter": record.knob,
        "effort_value": record.knob_value,
        "effort_passes": record.passes,
        "effort_note": record.note,
    }


def _add_standing(summary: pd.DataFrame, task: str, success_threshold: float) -> None:
    """Add ``task``'s ranking among the qualified controllers and the ratios to SNAC, the paper and the optimum."""
    p = f"{task}_"
    ranked = summary[p + "success_rate"].notna() & (summary["controller"] != OPTIMAL)
    summary[p + "qualified"] = ranked & (summary[p + "success_rate"] >= success_threshold)
    qualified_cost = summary[p + "cost"].where(summary[p + "qualified"])
    summary[p + "rank"] = qualified_cost.rank(method="min")
    summary[p + "ratio_to_best"] = qualified_cost / qualified_cost.min() if qualified_cost.notna().any() else math.nan
    snac = qualified_cost[summary["controller"] == "snac"]
    summary[p + "ratio_to_snac"] = (
        qualified_cost / float(snac.iloc[0]) if len(snac) and snac.notna().all() else math.nan
    )
    paper_snac = paper_value("snac", task)
    summary[p + "paper_ratio_to_snac"] = [
        (v / paper_snac) if v is not None and paper_snac else math.nan for v in summary[p + "paper"]
    ]
    optimum = summary.loc[summary["controller"] == OPTIMAL, p + "cost"]
    if len(optimum):
        summary[p + "ratio_of_means_to_optimal"] = summary[p + "cost"] / float(optimum.iloc[0])


__all__ = [
    "CONVENTION_COLUMNS",
    "PAIRED_REFERENCES",
    "PAPER_LABELS",
    "PAPER_TABLE_I",
    "controller_label",
    "mean_confidence_interval",
    "paper_value",
    "summarise",
]
