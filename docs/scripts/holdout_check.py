"""Count, per held-out run folder, the contestant-sample pairs below the reference: inside the joint
limits (a bug of the reference, if any) and, apart, those that cross a limit. Also the reference's own
limit margin, convergence and winners, and its gap to the certified lower bound where there is one.

Usage: python docs/scripts/holdout_check.py runs/holdout/*/results.csv [--markdown]
(a folder's ``<name>-velocity`` sibling, the velocity-only reference of the same samples, is compared
with the rollouts that cross a limit)
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

for path in sys.argv[1:]:
    if path == "--markdown" or Path(path).parent.name.endswith("-velocity"):
        continue
    rows = pd.read_csv(path)
    reference = rows[rows["controller"] == "optimal"]
    others = rows[rows["controller"] != "optimal"]
    inside = others["joint_limit_margin"] >= 0.0
    below = others["below_optimal"].astype(bool)
    print(
        f"{path}: {reference['task'].value_counts().to_dict()} samples, {others['controller'].nunique()} contestants "
        f"{sorted(others['controller'].unique())}"
    )
    print(
        f"  pairs inside the limits: {int(inside.sum())}, below the reference: {int((inside & below).sum())}"
        f" (min ratio {others.loc[inside, 'ratio_to_optimal'].min():.4f})"
    )
    print(
        f"  pairs crossing a limit: {int((~inside).sum())}, of which below the reference: "
        f"{int((~inside & below).sum())}"
    )
    print(
        f"  reference: min limit margin {reference['joint_limit_margin'].min():.2e} rad, peak |u|/ū "
        f"{reference['peak_limit_fraction'].max():.4f}, converged {reference['optimal_converged'].mean():.1%}, "
        f"limit binding (margin < 1e-6) on {int((reference['joint_limit_margin'] < 1e-6).sum())}, winners "
        f"{reference['optimal_winner'].value_counts().to_dict()}"
    )
    free_path = Path(path).parent.with_name(Path(path).parent.name + "-velocity") / "results.csv"
    if free_path.exists():
        free = pd.read_csv(free_path).set_index(["task", "sample"])
        crossing = others[~inside]
        bound = free["cost"].reindex(pd.MultiIndex.from_frame(crossing[["task", "sample"]])).to_numpy()
        print(
            f"  velocity-only reference: crosses a joint limit on {int((free['joint_limit_margin'] < 0).sum())} "
            f"of {len(free)} samples; pairs crossing a limit below it: "
            f"{int((crossing['cost'].to_numpy() < bound).sum())}"
        )
    if "optimal_lower_bound" in reference and reference["optimal_lower_bound"].notna().any():
        gap = (reference["cost"] / reference["optimal_lower_bound"]).groupby(reference["task"])
        print(
            f"  optimum / lower bound: median {gap.median().round(2).to_dict()}, p95 "
            f"{gap.quantile(0.95).round(2).to_dict()}"
        )
    if (inside & below).any():
        print(others.loc[inside & below, ["task", "controller", "sample", "ratio_to_optimal"]].to_string())


def markdown_row(path: str) -> str:
    """One row of docs/optimality.md's held-out table for a run folder's results.csv."""
    rows = pd.read_csv(path)
    reference = rows[rows["controller"] == "optimal"]
    others = rows[rows["controller"] != "optimal"]
    inside = others["joint_limit_margin"] >= 0.0
    below = others["below_optimal"].astype(bool)
    free_path = Path(path).parent.with_name(Path(path).parent.name + "-velocity") / "results.csv"
    crossing, free_text = others[~inside], "—"
    if free_path.exists():
        free = pd.read_csv(free_path).set_index(["task", "sample"])
        bound = free["cost"].reindex(pd.MultiIndex.from_frame(crossing[["task", "sample"]])).to_numpy()
        free_text = (
            f"{int((free['joint_limit_margin'] < 0).sum())} / {int((crossing['cost'].to_numpy() < bound).sum())}"
        )
    gap = (reference["cost"] / reference["optimal_lower_bound"]).groupby(reference["task"])
    return (
        f"| {Path(path).parent.name} | {len(reference)} | {others['controller'].nunique()} | {int(inside.sum())} | "
        f"**{int((inside & below).sum())}** | {others.loc[inside, 'ratio_to_optimal'].min():.4f} | "
        f"{int((~inside).sum())} / {int((~inside & below).sum())} | {free_text} | "
        f"{int((reference['joint_limit_margin'] < 1e-6).sum())} | "
        f"{gap.median().get('reach', float('nan')):.2f} / {gap.median().get('track', float('nan')):.2f} | "
        f"{gap.quantile(0.95).get('reach', float('nan')):.2f} / {gap.quantile(0.95).get('track', float('nan')):.2f} |"
    )


if __name__ == "__main__" and "--markdown" in sys.argv:
    for path in sys.argv[1:]:
        if path != "--markdown" and not Path(path).parent.name.endswith("-velocity"):
            print(markdown_row(path))
