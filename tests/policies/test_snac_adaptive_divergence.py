"""``snac-adaptive`` watching itself: its divergence bounds, the flag in the results, the fallback, the real arm told.

A divergence is forced by an error the identifier is not allowed to correct (a prior of 1e-9 m and
rad and a measurement noise of 1 km: Ĵ stays the model's) and that turns the command away from the error: the model
reads the base joint 2 rad off, so Ĵ = Rz(2)·J and the loop ė = −J R⁻¹JᵀRz(−2)P̂e turns the error by 115° in the
horizontal plane. Without the monitor that episode runs away silently.
"""

import numpy as np
import pytest
from snac_gym.evaluation.execution.jobs import RolloutJob, policy_context, run_job, task_kinematics
from snac_gym.evaluation.samples import generate_samples

from snac_gym.model.kinematics import Kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.policies.snac_adaptive import DivergenceMonitor
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

DT = 1 / 125
TURNED = "joint_offset=2.0,0,0,0,0,0"
COMBINED = "joint_offset=0,0.3,0.5,0,0.3,0;link_scale=-0.1;tool_offset=0.05,0.05,0.07"
FROZEN = {"prior_translation": 1e-9, "prior_rotation": 1e-9, "measurement_noise": 1e3}
#: The same, and the prediction residual's bound out of reach: only the task error's bounds can fire.
ERROR_RULES_ONLY = {**FROZEN, "divergence_residual": 100.0}


def _samples(task, count=3, seed=13):
    kinematics = Kinematics("ur10")
    return generate_samples(kinematics, SampleSpace.for_robot(kinematics), seed, task, range(count))


def _rollouts(task, model_error, steps=250, **kwargs):
    context = policy_context("ur10", DT, task, model_error)
    samples = _samples(task)
    rollouts = simulate_kinematic(
        context, lambda: make_policy("snac-adaptive", context, **kwargs), samples, steps, range(len(samples)),
        plant=task_kinematics("ur10", task),
    )  # fmt: skip
    return rollouts


def test_a_monitor_passes_a_decaying_error_and_flags_each_bound_at_its_step():
    monitor = DivergenceMonitor(DT)
    count = 7
    monitor.reset(count)
    window, patience, settle = monitor.window, monitor.patience, monitor.settle
    for k in range(400):
        decaying = 0.5 * np.exp(-2.0 * k * DT)  # a converging reach: 0.5 m at 2/s, as predicted
        slow = 0.3 - 0.0004 * k  # 5 cm/s, as predicted (a velocity limit): 0.2 m left at 2 s, 4 s to go
        growing = 0.3 + 0.0011 * k  # more than 5 cm past its start from k = 46
        short = 0.10  # 10 cm and not moving, where the controller predicts 0.5 mm a step
        stuck = 0.10  # 10 cm and not moving, as the controller predicts (Ĵᵀe = 0)
        crawling = 0.3 - 0.0001 * k  # 1.25 cm/s, as predicted (a singular direction): 22 s to go at 2 s
        norms = np.array([decaying, slow, growing, short, stuck, 0.0, crawling])
        predicted = np.array([0.5 * np.exp(-2.0 * (k + 1) * DT), slow - 0.0004, growing - 0.0005, short - 0.0005,
                              stuck, 0.0, crawling - 0.0001])  # fmt: skip
        residual = np.array([0, 0, 0, 0, 0, 0.02 if k >= 10 else 0.0, 0])  # 2 cm from step 10, before the settling time
        monitor.check(norms, residual, predicted)
    assert monitor.diverged.tolist() == [False, False, True, True, True, True, True]
    assert monitor.reason[2:].tolist() == ["error grew", "progress fell short of the prediction", "no progress",
                                           "prediction residual", "too slow"]  # fmt: skip
    assert monitor.step[2] == 46  # the first step more than 5 cm above ‖e₀‖
    # 0.5 mm a step predicted, none measured: a shortfall of 1 cm (and half the prediction) after 20 steps, once
    # a whole window of measurements is in
    assert monitor.step[3] == window
    assert monitor.step[4] == patience  # no progress needs the whole 2 s
    assert monitor.step[5] == settle  # the residual bound waits for the identifier's first correction
    assert monitor.step[6] == patience  # too slow: judged on the same 2 s
    assert monitor.describe(0) == "" and monitor.describe(4) == f"no progress at step {patience}"


@pytest.mark.parametrize("time_to_go, flagged", [(6.0, True), (30.0, False)])
def test_too_slow_is_the_time_the_recent_progress_needs_to_close_the_error(time_to_go, flagged):
    """25 cm left after 2 s at 2.5 cm/s: 10 s to go, more than 6 s and less than 30 s."""
    monitor = DivergenceMonitor(DT, time_to_go=time_to_go)
    monitor.reset(1)
    for k in range(monitor.patience + 1):
        norm = np.array([0.3 - 0.0002 * k])
        monitor.check(norm, np.zeros(1), norm - 0.0002)
    assert monitor.diverged[0] == flagged


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("bounds", ["all bounds", "the error's bounds only"])
def test_a_forced_divergence_is_flagged_and_the_arm_stops_from_that_step(task, bounds):
    rollouts = _rollouts(task, TURNED, **(FROZEN if bounds == "all bounds" else ERROR_RULES_ONLY))
    flags = rollouts.flags
    assert flags is not None and flags["diverged"].all()
    for i, step in enumerate(flags["diverged_step"]):
        assert 0 < step < rollouts.steps
        assert np.any(rollouts.commands[i, step - 1] != 0)  # it moved until then
        np.testing.assert_array_equal(rollouts.commands[i, step:], 0.0)  # the fallback: a stop, held


def test_the_stop_bounds_the_error_where_without_it_the_error_runs_away():
    """``fallback="none"`` keeps the adaptive command: the flag comes at the same step, and the error then runs
    away, where the stop holds it within the growth bound (plus the last period's motion)."""
    watched = _rollouts("reach", TURNED, **ERROR_RULES_ONLY)
    unwatched = _rollouts("reach", TURNED, fallback="none", **ERROR_RULES_ONLY)
    np.testing.assert_array_equal(watched.flags["diverged_step"], unwatched.flags["diverged_step"])
    start = np.linalg.norm(watched.errors[:, 0], axis=1)
    bound = start + DivergenceMonitor(DT).growth + 0.01
    assert (np.linalg.norm(watched.errors, axis=2).max(axis=1) <= bound).all()
    assert (np.linalg.norm(unwatched.errors, axis=2).max(axis=1) > bound).any()


def test_the_results_carry_the_flag_and_its_time_and_leave_it_empty_for_controllers_that_do_not_watch():
    common = {"task": "reach", "samples": tuple(_samples("reach")), "seeds": (0, 1, 2), "steps": 250, "dt": DT}
    forced = run_job(RolloutJob(controller="snac-adaptive", kwargs=FROZEN, model_error=TURNED, **common)).metrics
    assert forced["diverged"].tolist() == [True, True, True]
    assert (forced["diverged_time"] > 0).all() and (forced["diverged_time"] < 250 * DT).all()
    healthy = run_job(RolloutJob(controller="snac-adaptive", kwargs={}, model_error=COMBINED, **common)).metrics
    assert healthy["diverged"].tolist() == [False, False, False]  # the identifier corrects this one
    assert healthy["diverged_time"].isna().all()
    other = run_job(RolloutJob(controller="lqr", kwargs={}, **common)).metrics
    assert other["diverged"].isna().all()  # not False: lqr does not watch itself


def test_a_real_arm_is_stopped_through_its_safety_layer_when_the_controller_diverges(tmp_path):
    from snac_gym.apps.real import run_real_episode
    from snac_gym.real import SafetyLimits

    # a loaded CI machine may be late now and then: the deadline rule has its own tests (tests/real/test_env.py)
    lenient = SafetyLimits(max_missed_deadlines=10**5, deadline_window=10**5, max_period=10.0)
    result = run_real_episode(
        task="reach", controller="snac-adaptive", out_dir=tmp_path, connection="sim", steps=80, plots=False,
        model_error=TURNED, policy_kwargs=FROZEN, safety=lenient,
    )  # fmt: skip
    assert result.stop_reason is not None and result.stop_reason.startswith("the controller diverged: ")
    log = result.demo.log
    flagged = int(np.argmax(log["diverged"].to_numpy() > 0))
    assert 0 < flagged < 80 and len(log) == flagged + 1  # the period it was flagged in is the last


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("fallback", "brake", "fallback must be one of stop, none"),
        ("divergence_shortfall", 0.0, "divergence_shortfall"),
        ("divergence_growth", -0.1, "divergence_growth"),
        ("prior_translation", 0.0, "prior_translation"),
    ],
)
def test_a_bad_monitor_or_prior_argument_is_refused_naming_it(name, value, message):
    context = policy_context("ur10", DT, "reach", None)
    with pytest.raises(ValueError, match=message):
        make_policy("snac-adaptive", context, **{name: value})


def test_the_demo_says_whether_the_controller_diverged():
    from snac_gym.apps.demo import run_demo

    forced = run_demo("reach", "snac-adaptive", None, steps=60, model_error=TURNED, policy_kwargs=FROZEN)
    flagged = int(np.argmax(forced.log["diverged"].to_numpy() > 0))
    assert f"diverged                    YES at step {flagged} " in forced.summary()
    commands = forced.log[[f"u_{j}" for j in range(6)]].to_numpy()
    assert flagged > 0 and np.any(commands[:flagged] != 0)
    np.testing.assert_array_equal(commands[flagged:], 0.0)  # stopped from then on
    healthy = run_demo("reach", "snac-adaptive", None, steps=30)
    assert "diverged                    no (no divergence bound crossed)" in healthy.summary()
    assert "diverged" not in run_demo("reach", "lqr", None, steps=5).summary()
