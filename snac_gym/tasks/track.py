"""Tracking (Section IV): follow a point moving on an ellipse, with its velocity known."""

from __future__ import annotations

from typing import Any

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.references import MIN_SEMI_AXIS, PAPER_CIRCLE_SPEED, Ellipse
from snac_gym.sampling import SampleSpace, check_reachable, sample_ellipse
from snac_gym.tasks.base import CellReader, Task

ELLIPSE_COLUMNS = (
    "centre_0",
    "centre_1",
    "centre_2",
    "semi_axis_0",
    "semi_axis_1",
    "orientation_0",
    "orientation_1",
    "orientation_2",
    "angular_speed",
    "phase",
)
#: Defaults of the optional ellipse columns: a horizontal ellipse at the paper's speed, phase 0.
OPTIONAL_ELLIPSE_DEFAULTS = {
    "orientation_0": 0.0,
    "orientation_1": 0.0,
    "orientation_2": 0.0,
    "angular_speed": PAPER_CIRCLE_SPEED,
    "phase": 0.0,
}


class EllipseTrackTask(Task[Ellipse]):
    """Follow x_d(t) on an ellipse; success is a mean error over the second half within 5 mm."""

    name = "track"
    label = "Tracking"
    code = 1
    option_key = "ellipse"
    env_name = "EllipseTrack"
    moving_reference = True
    success_tolerance = 5e-3
    success_measure = "mean_error_2nd_half"
    accuracy_measure = "median_error_2nd_half"
    accuracy_text = "median error over the 2nd half"
    episode_steps = 2500
    horizon_s = 20.0
    real_horizon_s = 30.0
    csv_columns = ELLIPSE_COLUMNS

    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> Ellipse:
        return sample_ellipse(kinematics, rng, space)

    def paper(self) -> Ellipse:
        return Ellipse.paper_circle()

    def scaled(self, reference: Ellipse, factor: float) -> Ellipse:
        return reference.scaled(factor)

    def parse(self, value: Any, kinematics: Kinematics) -> Ellipse:
        ellipse = value if isinstance(value, Ellipse) else Ellipse.from_dict(value)
        check_reachable(kinematics, ellipse.points(64), f"options[{self.option_key!r}]")
        return ellipse

    def option_value(self, reference: Ellipse) -> dict[str, Any]:
        return reference.to_dict()

    def csv_cells(self, reference: Ellipse) -> dict[str, float]:
        values = [
            *reference.centre,
            *reference.semi_axes,
            *reference.orientation,
            reference.angular_speed,
            reference.phase,
        ]
        return dict(zip(ELLIPSE_COLUMNS, (float(v) for v in values), strict=True))

    def read_csv_reference(self, cells: CellReader) -> Ellipse:
        semi_axes = cells.numbers(["semi_axis_0", "semi_axis_1"])
        for i, value in enumerate(semi_axes):
            if value < MIN_SEMI_AXIS:
                raise cells.error(f"semi_axis_{i}", f"{value} m must be positive, at least {MIN_SEMI_AXIS:g} m")
        optional = {name: cells.number(name, default) for name, default in OPTIONAL_ELLIPSE_DEFAULTS.items()}
        centre = cells.numbers(["centre_0", "centre_1", "centre_2"])
        try:
            return Ellipse(
                centre=centre,
                semi_axes=semi_axes,
                orientation=[optional[f"orientation_{i}"] for i in range(3)],
                angular_speed=optional["angular_speed"],
                phase=optional["phase"],
            )
        except ValueError as exc:  # a meaningless ellipse (its speed): the constructor states the bound
            raise cells.error(self.csv_reference_span(), str(exc)) from None
