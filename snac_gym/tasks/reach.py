"""Regulation (Section III): bring the end effector to a fixed target point and keep it there."""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.references import PAPER_TARGET, FixedTarget
from snac_gym.sampling import SampleSpace, check_reachable, sample_target
from snac_gym.tasks.base import CellReader, Task

TARGET_COLUMNS = ("target_0", "target_1", "target_2")


class ReachTask(Task[FixedTarget]):
    """Reach a fixed target x_d (ẋ_d = 0); success is a final error within 1 mm."""

    name = "reach"
    label = "Regulation"
    code = 0
    option_key = "target"
    env_name = "Reach"
    success_tolerance = 1e-3
    success_measure = "final_error"
    accuracy_measure = "final_error"
    episode_steps = 1000
    # 12 s: SNAC's 95th-percentile settling time at equal effort is 11.7 s (docs/evaluation.md).
    horizon_s = 12.0
    real_horizon_s = 15.0
    csv_columns = TARGET_COLUMNS

    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> FixedTarget:
        return sample_target(kinematics, rng, space)

    def paper(self) -> FixedTarget:
        return FixedTarget(PAPER_TARGET)

    def scaled(self, reference: FixedTarget, factor: float) -> FixedTarget:
        return FixedTarget(reference.target * factor)

    def parse(self, value: Any, kinematics: Kinematics) -> FixedTarget:
        target = value if isinstance(value, FixedTarget) else FixedTarget(value)
        check_reachable(kinematics, target.points(), f"options[{self.option_key!r}]")
        return target

    def option_value(self, reference: FixedTarget) -> list[float]:
        return cast("list[float]", reference.target.tolist())  # a (3,) float array

    def csv_cells(self, reference: FixedTarget) -> dict[str, float]:
        return dict(zip(TARGET_COLUMNS, reference.target.tolist(), strict=True))

    def read_csv_reference(self, cells: CellReader) -> FixedTarget:
        return FixedTarget(cells.numbers(TARGET_COLUMNS))
