"""Matched knobs and V/N of two runs of one seed that differ only in --samples (docs/evaluation.md).

    snac-gym evaluate --out runs/es200 --samples 200 --controllers snac,snac-hjb,lqr,rnn,svf,dls --workers 2
    snac-gym evaluate --out runs/es1000 --samples 1000 --controllers snac,snac-hjb,lqr,rnn,svf,dls --workers 2
    python docs/scripts/effort_set_stability.py runs/es200 runs/es1000

Prints, per task and controller, the matched knob of each run, V/N of each run, and V/N of the
larger run's rollouts on the smaller run's samples ("same samples"): its difference from the
smaller run's V/N is the part of the change that the knob makes; the rest is the sampling error
of a mean cost.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd


def main(small: str, large: str) -> None:
    few, many = (pd.read_parquet(Path(p) / "results.parquet") for p in (small, large))
    indices = set(few["sample"])
    print("| task | controller | knob (few → many) | V/N few → many | V/N many, same samples | by the knob |")
    print("|---|---|---|---|---|---|")
    for (task, controller), rows in few.groupby(["task", "controller"], sort=False):
        other = many[(many["task"] == task) & (many["controller"] == controller)]
        same = other[other["sample"].isin(indices)]
        knob_few, knob_many = rows["effort_value"].iloc[0], other["effort_value"].iloc[0]
        v_few, v_many, v_same = rows["cost"].mean(), other["cost"].mean(), same["cost"].mean()
        knob = (
            "—"
            if pd.isna(knob_few)
            else f"{knob_few:.6g} → {knob_many:.6g} ({100 * (knob_few / knob_many - 1):+.2f} %)"
        )
        print(
            f"| {task} | {controller} | {knob} | {v_few:.1f} → {v_many:.1f} ({100 * (v_few / v_many - 1):+.1f} %) "
            f"| {v_same:.1f} | {100 * (v_few / v_same - 1):+.2f} % |"
        )


if __name__ == "__main__":
    main(*sys.argv[1:3])
