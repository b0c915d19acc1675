"""The optimality-gap section of ``summary.md``: each controller's cost against the trajectory optimum, the
solver's certificates, and the samples where a controller came out below the optimum.

Part of :mod:`snac_gym.evaluation.reports.writer` (written only when the run has the ``optimal`` reference).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import pandas as pd
from snac_gym.evaluation.reference.optimum import OPTIMAL, OWN_STARTS
from snac_gym.evaluation.reports.tables import general_number

from snac_gym.control.trajopt import FTOL, GAP_RTOL

__all__ = ["optimality_markdown"]


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
                f"| {t} | {row['label']} | {general_number(row[p + 'cost'])} | "
                f"{general_number(row[p + 'ratio_to_optimal_mean'])} | "
                f"{general_number(row[p + 'ratio_to_optimal_median'])} | "
                f"{general_number(row[p + 'ratio_of_means_to_optimal'])} | {below} | {crossing} |"
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
