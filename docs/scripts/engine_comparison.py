"""Table I in each engine, sample by sample: how far the MuJoCo and PyBullet runs are from the kinematic one.

Reads three ``snac-gym evaluate`` output folders of the same samples and settings, one per engine,
and prints, per task and controller: V/N (the mean Table I cost) and success in each engine, and for
each physics engine against the kinematic model the per-sample relative difference |ΔV|/V (median
and largest), the paired mean difference of V with its 95 % confidence interval, the Wilcoxon
signed-rank p-value of the paired differences, and how many samples change success.

    for e in kinematic mujoco pybullet; do
      snac-gym evaluate --out runs/t1_$e --engine $e --samples 1000 --workers 2 --no-match-effort \\
        --controllers snac,snac-hjb,lqr,rnn,svf,dls,ppo
    done
    python docs/scripts/engine_comparison.py runs/t1_kinematic runs/t1_mujoco runs/t1_pybullet
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats


def _load(folder: str) -> pd.DataFrame:
    return pd.read_parquet(Path(folder) / "results.parquet").set_index(["task", "controller", "sample"]).sort_index()


def _paired(base: pd.DataFrame, other: pd.DataFrame) -> dict[str, float]:
    v0, v1 = base["cost_table1"].to_numpy(), other["cost_table1"].to_numpy()
    diff = v1 - v0
    relative = np.abs(diff) / np.abs(v0)
    half = stats.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff))
    p = stats.wilcoxon(diff).pvalue if np.any(diff != 0) else 1.0
    return {
        "median_rel": float(np.median(relative)),
        "max_rel": float(relative.max()),
        "mean_diff": float(diff.mean()),
        "ci": float(half),
        "p": float(p),
        "success_changes": int((base["success"].to_numpy() != other["success"].to_numpy()).sum()),
    }


def main(kinematic: str, mujoco: str, pybullet: str) -> None:
    runs = {"kinematic": _load(kinematic), "MuJoCo": _load(mujoco), "PyBullet": _load(pybullet)}
    base = runs["kinematic"]
    for name, run in runs.items():
        if not run.index.equals(base.index):
            raise SystemExit(f"{name}'s run does not hold the kinematic run's (task, controller, sample) rows")
    print(
        "| task | controller | V/N: kinematic / MuJoCo / PyBullet | success % | |ΔV|/V median, max: MuJoCo; PyBullet "
        "| paired mean ΔV [95 % CI], Wilcoxon p: MuJoCo; PyBullet | success changes |"
    )
    print("|---|---|---|---|---|---|---|")
    for task, controller in base.index.droplevel("sample").unique():
        rows = {name: run.loc[(task, controller)] for name, run in runs.items()}
        means = " / ".join(f"{rows[n]['cost_table1'].mean():.2f}" for n in runs)
        success = " / ".join(f"{100 * rows[n]['success'].mean():.1f}" for n in runs)
        pairs = {n: _paired(rows["kinematic"], rows[n]) for n in ("MuJoCo", "PyBullet")}
        rel = "; ".join(f"{pairs[n]['median_rel']:.1e}, {pairs[n]['max_rel']:.1e}" for n in pairs)
        paired = "; ".join(
            f"{pairs[n]['mean_diff']:+.3g} [±{pairs[n]['ci']:.2g}], p={pairs[n]['p']:.2g}" for n in pairs
        )
        changes = " / ".join(str(pairs[n]["success_changes"]) for n in pairs)
        print(f"| {task} | {controller} | {means} | {success} | {rel} | {paired} | {changes} |")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        raise SystemExit("usage: engine_comparison.py KINEMATIC_RUN MUJOCO_RUN PYBULLET_RUN")
    main(*sys.argv[1:])
