"""The two tasks of the paper: what the reference is, how it is sampled or pinned, and success."""

from __future__ import annotations

from typing import Any

import numpy as np

from snac_gym.kinematics import Kinematics
from snac_gym.references import PAPER_TARGET, Ellipse, FixedTarget, Reference
from snac_gym.sampling import SampleSpace, check_reachable, sample_ellipse, sample_target


class Task:
    """Base class: a named reference family."""

    name: str
    option_key: str

    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> Reference:
        raise NotImplementedError

    def paper(self) -> Reference:
        raise NotImplementedError

    def parse(self, value: Any, kinematics: Kinematics) -> Reference:
        raise NotImplementedError


class ReachTask(Task):
    """Regulation (Section III): reach a fixed target point."""

    name = "reach"
    option_key = "target"

    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> FixedTarget:
        return sample_target(kinematics, rng, space)

    def paper(self) -> FixedTarget:
        return FixedTarget(PAPER_TARGET)

    def parse(self, value: Any, kinematics: Kinematics) -> FixedTarget:
        target = value if isinstance(value, FixedTarget) else FixedTarget(value)
        check_reachable(kinematics, target.points(), "options['target']")
        return target


class EllipseTrackTask(Task):
    """Tracking (Section IV): follow a point moving on an ellipse."""

    name = "track"
    option_key = "ellipse"

    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> Ellipse:
        return sample_ellipse(kinematics, rng, space)

    def paper(self) -> Ellipse:
        return Ellipse.paper_circle()

    def parse(self, value: Any, kinematics: Kinematics) -> Ellipse:
        ellipse = value if isinstance(value, Ellipse) else Ellipse.from_dict(value)
        check_reachable(kinematics, ellipse.points(64), "options['ellipse']")
        return ellipse


TASKS: dict[str, type[Task]] = {"reach": ReachTask, "track": EllipseTrackTask}
