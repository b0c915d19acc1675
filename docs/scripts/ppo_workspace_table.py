"""The table of docs/ppo.md "ppo-workspace": success, median cost over the optimum, failures, and the paired
comparison of ``ppo-workspace`` with ``joint-goal`` (the controller it corrects), per evaluator run folder.

    python docs/scripts/ppo_workspace_table.py runs/ppo_goal/final_*_*_*

Success is the evaluator's (error rule and joint limits); the ratio is the controller's HJB cost over the
optimum's on the same sample (median over samples); "limit" counts rollouts that crossed a joint limit, and
"below_optimum_in_limits" those that cost less than the optimum while keeping every limit (a failure of the
reference; a rollout that crosses a limit may cost less, since the optimum keeps them).
The paired columns: the median over samples of ppo-workspace's cost over joint-goal's, the share of samples
where it is cheaper, and the two-sided Wilcoxon signed-rank p-value of the log ratio.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import wilcoxon


def rows(folder: Path) -> list[dict]:
    frame = pd.read_csv(folder / "results.csv")
    task = frame.task.iloc[0]
    _, space, seed = folder.name.rsplit("_", 2)
    costs = frame.pivot(index="sample", columns="controller", values="cost_hjb")
    out = []
    for controller, group in frame.groupby("controller", sort=False):
        if controller == "optimal":
            continue
        row = {
            "task": task,
            "space": space,
            "seed": int(seed),
            "controller": controller,
            "success": group.success.astype(bool).mean(),
            "ratio_median": group.ratio_to_optimal.median(),
            "limit": int((group.joint_limit_margin < 0).sum()),
            # below the optimum while keeping every limit: a failure of the reference
            "below_optimum_in_limits": int((group.below_optimal.astype(bool) & (group.joint_limit_margin >= 0)).sum()),
        }
        if controller == "ppo-workspace" and "joint-goal" in costs:
            paired = costs["ppo-workspace"] / costs["joint-goal"]
            row.update(
                vs_joint_goal=paired.median(), cheaper=(paired < 1).mean(), wilcoxon_p=wilcoxon(np.log(paired)).pvalue
            )
        out.append(row)
    return out


if __name__ == "__main__":
    table = pd.DataFrame([row for arg in sys.argv[1:] for row in rows(Path(arg))])
    with pd.option_context("display.width", 220, "display.max_columns", 20, "display.max_rows", 200):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
