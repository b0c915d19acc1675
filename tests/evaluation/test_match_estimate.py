"""A run that matches effort first says how long a pass over the effort set takes where that is long (a controller as
slow as ``mpc``), measured on the workers before the match starts: the step cost of each controller
(:func:`~snac_gym.evaluation.execution.jobs.time_job`), the pass it implies, and the pass of the evaluated samples
alone."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from snac_gym.baselines.dls import DLSPolicy
from snac_gym.evaluation import runner
from snac_gym.evaluation.controllers import resolve_controllers
from snac_gym.evaluation.execution import passes
from snac_gym.evaluation.execution.executors import SerialExecutor
from snac_gym.evaluation.execution.jobs import RolloutJob, time_job
from snac_gym.evaluation.execution.passes import step_costs
from snac_gym.evaluation.run_config import EvaluationConfig
from snac_gym.evaluation.runner import announce_matching
from snac_gym.evaluation.samples import generate_samples

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.policies.registry import register_policy
from snac_gym.sampling import SampleSpace

#: What the slow test controller sleeps per sample and step (s).
SLEEP_S = 1e-3


class _SlowDLS(DLSPolicy):
    """DLS that sleeps :data:`SLEEP_S` per sample at every step: a controller whose steps cost a known time."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        time.sleep(SLEEP_S)
        return super().act(obs)

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        time.sleep(SLEEP_S * len(obs_batch))
        return super().act_batch(obs_batch)


def _samples(task: str, count: int) -> list:
    ur10 = shared_kinematics("ur10")
    return generate_samples(ur10, SampleSpace.for_robot(ur10), 0, task, range(count))


def test_a_jobs_step_cost_is_per_sample_and_step_and_counts_what_the_controller_spends():
    register_policy("estimate-slow-dls", _SlowDLS, overwrite=True)
    samples = tuple(_samples("reach", 8))
    job = RolloutJob("reach", "estimate-slow-dls", {}, samples, tuple(range(8)), steps=12, dt=1 / 125)
    cost = time_job(job)
    # The sleep, give or take what the scheduler's jitter does to the two-step run the rate is taken relative to; well
    # under what a cost per step (8 samples: 8 ms) or per job would be.
    assert 0.75 * SLEEP_S <= cost < 4 * SLEEP_S, cost


class _SlowStartDLS(DLSPolicy):
    """DLS that takes 50 ms to build: a cost of every job, whatever its length."""

    def __init__(self, *args, **kwargs) -> None:
        time.sleep(0.05)
        super().__init__(*args, **kwargs)


def test_what_a_job_costs_whatever_its_length_is_not_counted_as_steps():
    """50 ms per job over 8 samples and 10 steps would be 0.6 ms a sample-step; DLS's steps cost microseconds."""
    register_policy("estimate-slow-start-dls", _SlowStartDLS, overwrite=True)
    samples = tuple(_samples("reach", 8))
    job = RolloutJob("reach", "estimate-slow-start-dls", {}, samples, tuple(range(8)), steps=1500, dt=1 / 125)
    assert time_job(job) < 1e-4


def test_the_probe_times_every_controller_on_every_task_on_the_kinematic_model_with_few_samples(monkeypatch):
    register_policy("estimate-slow-dls", _SlowDLS, overwrite=True)
    monkeypatch.setattr(passes, "STEP_COST_SAMPLES", 8)  # not the 64 of a run: an eighth of the sleeps
    config = EvaluationConfig(out=Path("unused"), engine="pybullet", controllers=("dls", "estimate-slow-dls"))
    specs, _ = resolve_controllers(config)
    sets = {task: _samples(task, 13) for task in config.tasks}
    seen: list[RolloutJob] = []

    class Recording(SerialExecutor):
        def run(self, function, items, priority=0):
            seen.extend(items)
            return super().run(function, items, priority)

    costs = step_costs(config, Recording(), specs, sets)
    assert set(costs) == {(task, name) for task in ("reach", "track") for name in ("dls", "estimate-slow-dls")}
    assert all(job.engine == "kinematic" and len(job.samples) == 8 for job in seen)
    assert [job.steps for job in seen] == [1500, 1500, 2500, 2500]  # the horizons: time_job takes what it needs
    for task in config.tasks:
        assert costs[(task, "estimate-slow-dls")] >= 0.75 * SLEEP_S > costs[(task, "dls")], costs


def _config(**changes) -> EvaluationConfig:
    return EvaluationConfig(out=Path("unused"), **changes)


EFFORT_SET = {"reach": [0] * 1000, "track": [0] * 1000}
EVALUATED = {"reach": [0] * 50, "track": [0] * 50}
WHY = "no knobs cached or shipped for these controllers at these settings"


def test_a_long_match_says_how_long_one_pass_takes_and_a_pass_of_the_evaluated_samples_alone():
    """By hand: reach 1500 steps, track 2500; (1.2 ms + 5 µs) a sample-step × 1000 samples × 4000 steps = 4820 s, on 2
    workers 2410 s (40 min); the 50 evaluated samples' pass a twentieth of it, 120.5 s (2 min)."""
    costs = {("reach", "mpc"): 1.2e-3, ("track", "mpc"): 1.2e-3, ("reach", "snac"): 5e-6, ("track", "snac"): 5e-6}
    written: list[str] = []
    announce_matching(written.append, _config(), EVALUATED, EFFORT_SET, True, costs, workers=2)
    assert written == [
        f"evaluate: matching equal effort first, on 1000 samples a task ({WHY}); one pass of these controllers over "
        "them takes about 40 min here (2 workers; mpc: 1.2 ms a step), and matching takes several times that (a knob "
        "search of up to 40 tries on them, then one to 3 passes); --no-match-effort skips it, --effort-samples 0 "
        "matches on the evaluated samples (a pass of them: about 2 min)\n"
    ]
    # One worker: twice as long; with no larger effort set there is no shorter pass to offer.
    written.clear()
    announce_matching(written.append, _config(), EFFORT_SET, EFFORT_SET, True, costs, workers=1)
    assert "takes about 80 min here (1 worker; mpc: 1.2 ms a step)" in written[0]
    assert written[0].endswith("then one to 3 passes); --no-match-effort skips it\n"), written[0]


def test_a_quick_match_is_announced_as_before_without_a_duration():
    costs = {(task, name): 5e-6 for task in ("reach", "track") for name in ("snac", "lqr")}  # 40 s on one worker
    written: list[str] = []
    announce_matching(written.append, _config(), EVALUATED, EFFORT_SET, True, costs, workers=1)
    assert written == [
        f"evaluate: matching equal effort first, on 1000 samples a task ({WHY}); --no-match-effort skips it, "
        "--effort-samples 0 matches on the evaluated samples\n"
    ]


def test_a_run_that_matches_a_slow_controller_says_what_its_probe_measured(tmp_path, monkeypatch):
    """Through the command: the probe runs before the match, and its line names the slow controller at its cost."""
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    register_policy("estimate-slow-dls", _SlowDLS, overwrite=True)
    monkeypatch.setattr(runner, "LONG_MATCH_S", 0.01)  # the tiny run's pass is short: say it anyway
    arguments = ["evaluate", "--samples", "2", "--effort-samples", "4", "--horizon", "0.2", "--controllers",
                 "dls,estimate-slow-dls", "--effort-reference", "dls", "--no-plots"]  # fmt: skip
    arguments += ["--out", str(tmp_path / "run")]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, result.stderr
    found = re.search(r"; one pass of these controllers over them takes (about \d+ s|under a second) here \(1 worker; "
                      r"estimate-slow-dls: (\d+\.\d) ms a step\)", result.stderr)  # fmt: skip
    assert found is not None, result.stderr
    assert float(found.group(2)) >= SLEEP_S * 1e3
    assert "--effort-samples 0 matches on the evaluated samples (a pass of them: " in result.stderr


@pytest.mark.parametrize("seconds", [0.4, 0.6, 59.6, 75.0, 5000.0, 6000.0])
def test_durations_read_in_the_unit_one_thinks_of_them_in(seconds):
    expected = {0.4: "under a second", 0.6: "about 1 s", 59.6: "about 60 s", 75.0: "about 75 s", 5000.0: "about 83 min",
                6000.0: "about 1.7 h"}  # fmt: skip
    assert runner._about(seconds) == expected[seconds]
