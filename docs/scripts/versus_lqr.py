"""``snac-adaptive``'s cost over ``lqr``'s on every sample of an evaluation (both at the same weights).

python docs/scripts/versus_lqr.py runs/me_none_s41
"""

from __future__ import annotations

import sys

import pandas as pd


def main() -> None:
    results = pd.read_csv(f"{sys.argv[1]}/results.csv")
    costs = results.pivot_table(index=["task", "sample"], columns="controller", values="cost")
    ratio = costs["snac-adaptive"] / costs["lqr"]
    for task in ("reach", "track"):
        r = ratio.loc[task]
        print(f"{task}: median {r.median():.4f}, min {r.min():.4f}, max {r.max():.4f}, "
              f"{int(((r - 1).abs() > 0.02).sum())} of {len(r)} samples more than 2 % from lqr")  # fmt: skip


if __name__ == "__main__":
    main()
