"""Success, median cost over the optimum and the split of failures of each controller in evaluator runs.

    python docs/scripts/ppo_failures.py runs/ppo_ws/ev_reach_s11 [more run folders]

A rollout fails by crossing a joint limit (``joint_limit_margin < 0``) or by ending off target
(the task's error rule: reach final ‖e‖ > 1 mm, track mean ‖e‖ over the second half > 5 mm); a
rollout can do both. The ratio is the controller's HJB cost over the optimum's on the same sample
(``ratio_to_optimal``, median over the samples).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

THRESHOLD = {"reach": ("final_error", 1e-3), "track": ("mean_error_2nd_half", 5e-3)}


def summarise(folder: Path) -> list[dict]:
    frame = pd.read_csv(folder / "results.csv")
    rows = []
    for (task, controller), group in frame.groupby(["task", "controller"], sort=False):
        column, limit = THRESHOLD[task]
        crossed = group.joint_limit_margin < 0
        off = ~(group[column] <= limit)
        rows.append(
            {
                "run": folder.name,
                "task": task,
                "controller": controller,
                "n": len(group),
                "success": group.success.astype(bool).mean(),
                "ratio_median": group.ratio_to_optimal.median() if "ratio_to_optimal" in group else float("nan"),
                "fail": int((~group.success.astype(bool)).sum()),
                "limit_only": int((crossed & ~off).sum()),
                "off_only": int((off & ~crossed).sum()),
                "both": int((off & crossed).sum()),
            }
        )
    return rows


if __name__ == "__main__":
    table = pd.DataFrame([row for arg in sys.argv[1:] for row in summarise(Path(arg))])
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
