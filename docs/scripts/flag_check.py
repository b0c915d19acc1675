"""The divergence flag against the outcome: per run, task and controller, the success rate, the episodes flagged
``diverged``, those ending more than 5 cm off, and how many of those carry no flag (the invariant: none).
Controllers that do not watch themselves show "—" for the flags.

    python docs/scripts/flag_check.py runs/ur3_ws_s6202 [more run folders]
"""

from __future__ import annotations

import sys

import pandas as pd


def main() -> None:
    print("| run | task | controller | episodes | success | flagged | end > 5 cm off | of them unflagged |")
    print("|---|---|---|---|---|---|---|---|")
    for folder in sys.argv[1:]:
        results = pd.read_csv(f"{folder}/results.csv")
        for (task, controller), rows in results[results["controller"] != "optimal"].groupby(["task", "controller"]):
            watched = rows["diverged"].notna().any()
            raised = rows["diverged"].astype(str).str.lower() == "true"
            far = rows["final_error"] > 0.05
            flagged = str(int(raised.sum())) if watched else "—"
            unflagged = str(int((far & ~raised).sum())) if watched else "—"
            print(f"| {folder} | {task} | `{controller}` | {len(rows)} | {rows['success'].mean():.1%} | {flagged} | "
                  f"{int(far.sum())} | {unflagged} |")  # fmt: skip


if __name__ == "__main__":
    main()
