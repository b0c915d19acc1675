"""The reference's certificate gap on a run: per sample, the optimum over its certified lower bound (docs/optimal.md).

    python docs/scripts/bound_gap_figure.py runs/table1 docs/figures/bound_gap.png

Reads the run's ``results.parquet`` (the ``optimal`` rows' ``cost`` and ``optimal_lower_bound``), prints the median,
95th percentile and largest ratio per task, and draws their distribution.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

run, figure = Path(sys.argv[1]), Path(sys.argv[2])
results = pd.read_parquet(run / "results.parquet")
rows = results[results["controller"] == "optimal"]
fig, ax = plt.subplots(figsize=(6.4, 3.2), dpi=150)
ratios = rows["cost"] / rows["optimal_lower_bound"]
bins = np.geomspace(1.0, 1.1 * float(ratios.max()), 60)  # up to the largest gap: no empty decade
for task, label in (("reach", "regulation"), ("track", "tracking")):
    part = rows[rows["task"] == task]
    ratio = (part["cost"] / part["optimal_lower_bound"]).to_numpy()
    print(
        f"{task}: {len(ratio)} samples, optimum / bound median {np.median(ratio):.2f}, "
        f"95th percentile {np.percentile(ratio, 95):.2f}, largest {ratio.max():.2f}, below 1: {(ratio < 1).sum()}"
    )
    ax.hist(
        ratio,
        bins=bins,
        histtype="step",
        linewidth=1.5,
        label=f"{label} (median {np.median(ratio):.1f}, largest {ratio.max():.1f})",
    )
ax.set_xscale("log")
# Plain numbers at 1, 1.5, 2, 3, 5, 7 (a ratio reads as "2", not "2×10⁰").
ticks = [t for t in (1.0, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0, 20.0, 50.0) if t <= bins[-1]]
ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
ax.set_xlabel("optimum / certified lower bound (1 = tight)")
ax.set_ylabel("samples")
ax.axvline(2.0, color="grey", linestyle=":", linewidth=1, label="2× (the target median)")
ax.legend(frameon=False, loc="upper right")
ax.set_title("The reference's certificate gap, main command (1000 + 1000 samples)", fontsize=9)
fig.tight_layout()
fig.savefig(figure)
