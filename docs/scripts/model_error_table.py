"""The model-error table: each controller's success and median cost ratio to the true-model optimum.

Reads evaluation folders made with ``--cost hjb --q-scale 4 --no-match-effort`` and the same
samples, one per model error (``--model-error``, or none), and prints a Markdown table: per
controller and error, "reach success / track success" and "reach ratio / track ratio", the
median over samples of cost / optimal cost on the same sample (the optimum always has the true
model).

    python docs/scripts/model_error_table.py none=runs/me_none elbow=runs/me_elbow ...
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

LABELS = {"snac": "SNAC (paper)", "rnn": "RNN", "svf": "SVF", "dls": "DLS"}


def cells(folder: Path) -> dict[str, str]:
    results = pd.read_csv(folder / "results.csv")
    optimum = results[results["controller"] == "optimal"].set_index(["task", "sample"])["cost"]
    out: dict[str, str] = {}
    for controller, rows in results[results["controller"] != "optimal"].groupby("controller", sort=False):
        parts = []
        for task in ("reach", "track"):
            task_rows = rows[rows["task"] == task].set_index(["task", "sample"])
            ratio = (task_rows["cost"] / optimum.reindex(task_rows.index)).median()
            parts.append((f"{task_rows['success'].mean():.0%}", f"{ratio:.3f}"))
        out[controller] = f"{parts[0][0]} / {parts[1][0]}, {parts[0][1]} / {parts[1][1]}"
    return out


def watch_cells(folder: Path) -> str:
    """The controllers that watch themselves: episodes flagged ``diverged``, and those ending > 5 cm off without it."""
    results = pd.read_csv(folder / "results.csv")
    watched = results[results["diverged"].notna()] if "diverged" in results else results.iloc[:0]
    if watched.empty:
        return "—"
    flagged = watched["diverged"].astype(str).str.lower() == "true"
    far = watched["final_error"] > 0.05
    return (
        f"{int(flagged.sum())} flagged, {int(far.sum())} end > 5 cm off, {int((far & ~flagged).sum())} of them "
        "unflagged"
    )


def main() -> None:
    runs = dict(argument.rsplit("=", 1) for argument in sys.argv[1:])  # LABEL=FOLDER (a label may hold "=")
    table = {name: cells(Path(folder)) for name, folder in runs.items()}
    controllers = list(dict.fromkeys(c for column in table.values() for c in column))
    print("| controller | " + " | ".join(runs) + " |")
    print("|---|" + "---|" * len(runs))
    for controller in controllers:
        row = [table[name].get(controller, "—") for name in runs]
        print(f"| {LABELS.get(controller, '`' + controller + '`')} | " + " | ".join(row) + " |")
    print()
    print("| divergence flags (controllers that watch themselves, reach + track) | " + " | ".join(runs) + " |")
    print("|---|" + "---|" * len(runs))
    print("| `snac-adaptive` | " + " | ".join(watch_cells(Path(folder)) for folder in runs.values()) + " |")


if __name__ == "__main__":
    main()
