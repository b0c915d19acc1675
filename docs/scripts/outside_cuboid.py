"""Keep the first N reach and N track rows of a samples CSV whose target (reach) or ellipse centre
(track) lies outside the UR10's Table I cuboid: a held-out set outside the default ranges.

Usage: python docs/scripts/outside_cuboid.py SAMPLES.csv N   (rewrites the file in place)
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from snac_gym.sampling import SampleSpace

path, count = sys.argv[1], int(sys.argv[2])
rows = pd.read_csv(path)
space = SampleSpace()  # the UR10 cuboid of Table I
point = np.where(rows["task"].eq("reach").to_numpy()[:, None],
                 rows[["target_0", "target_1", "target_2"]].to_numpy(),
                 rows[["centre_0", "centre_1", "centre_2"]].to_numpy())  # fmt: skip
outside = rows[[not space.contains(p) for p in point]]
kept = pd.concat([outside[outside["task"] == task].head(count) for task in ("reach", "track")])
kept.to_csv(path, index=False)
print(f"{path}: {len(kept)} samples outside the cuboid ({(kept['task'] == 'reach').sum()} reach)")
