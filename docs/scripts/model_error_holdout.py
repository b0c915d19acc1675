"""The held-out model-error table: per run, task and controller, on target (the task's tolerance, joint limits
aside), rollouts past a joint limit, success, the median cost ratio to the optimum, divergence flags and the
rollouts ending more than 5 cm off.

    python docs/scripts/model_error_holdout.py none=runs/me_none_ws model=ur5=runs/me_ur5_ws ...
"""

from __future__ import annotations

import sys

import pandas as pd

TOLERANCE = {"reach": ("final_error", 1e-3), "track": ("mean_error_2nd_half", 5e-3)}


def main() -> None:
    print(
        "| error | task | controller | on target | past a joint limit | success | median ratio | flagged | "
        "end > 5 cm off (unflagged) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for argument in sys.argv[1:]:
        label, folder = argument.rsplit("=", 1)
        results = pd.read_csv(f"{folder}/results.csv")
        optimum = results[results["controller"] == "optimal"].set_index(["task", "sample"])["cost"]
        for (task, controller), rows in results[results["controller"] != "optimal"].groupby(["task", "controller"]):
            if controller == "dls":
                continue
            column, bound = TOLERANCE[task]
            ratio = (rows.set_index(["task", "sample"])["cost"] / optimum).dropna().median()
            watched = rows["diverged"].notna().any()
            raised = rows["diverged"].astype(str).str.lower() == "true"
            far = rows["final_error"] > 0.05
            flagged = int(raised.sum()) if watched else "—"
            unflagged = f" ({int((far & ~raised).sum())})" if watched else ""
            print(f"| {label} | {task} | `{controller}` | {(rows[column] <= bound).mean():.0%} | "
                  f"{int((rows['joint_limit_margin'] < 0).sum())} | {rows['success'].mean():.0%} | {ratio:.3f} | "
                  f"{flagged} | {int(far.sum())}{unflagged} |")  # fmt: skip


if __name__ == "__main__":
    main()
