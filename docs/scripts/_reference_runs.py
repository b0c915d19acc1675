"""What the scripts that time a finished run's reference share (``table1_floor.py``, ``reference_phases.py``,
``screen_tails.py``): the run's setting read back, and a reference job of the first samples of a task, warmed up."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from snac_gym.evaluation.reference.optimum import OptimalJob, run_optimal_job
from snac_gym.evaluation.samples import EvaluationSample, read_samples_csv

from snac_gym.control.cost import CostConvention
from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace


def run_setting(run: Path) -> tuple[dict[str, Any], Kinematics, dict[str, list[EvaluationSample]], CostConvention]:
    """``(run.json, the arm's kinematics, the samples by task, the cost)`` of the finished run in ``run``."""
    config = json.loads((run / "run.json").read_text())
    kinematics = Kinematics(config["robot"])
    samples = read_samples_csv(run / "samples.csv", kinematics, SampleSpace(**config["space"]))
    return config, kinematics, samples, CostConvention(config["cost"], config["udot_start"], config["q_scale"])


def reference_job(
    config: dict[str, Any], task: str, samples: list[EvaluationSample], count: int, convention: CostConvention
) -> OptimalJob:
    """The run's reference job of the first ``count`` of ``samples`` (of ``task``), without the cache, after a
    two-sample job of the same setting has run (the kernels compiled or loaded, the first calls made)."""
    chunk = tuple(samples[:count])
    job = OptimalJob(task, chunk, tuple(range(len(chunk))), config["steps"][task], config["dt"], config["robot"],
                     convention=convention, position_limits=config["reference_limits"] == "joints")  # fmt: skip
    run_optimal_job(OptimalJob(task, chunk[:2], (0, 1), job.steps, job.dt, job.robot, convention=convention))
    return job
