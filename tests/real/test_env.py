"""The real-robot env on the simulated connection: the whole loop and every safety rule."""

import importlib.util
import json
import time

import numpy as np
import pandas as pd
import pytest

import snac_gym.real.connections as connections
from snac_gym.common.errors import MissingExtraError
from snac_gym.policies.base import BasePolicy
from snac_gym.real import (
    EMERGENCY_STOP,
    NORMAL,
    PROTECTIVE_STOP,
    ConnectionFailure,
    DryRunConnection,
    RealUREnv,
    SafetyLimits,
    SimulatedConnection,
    URRTDEConnection,
)
from snac_gym.references import PAPER_Q0, PAPER_TARGET


class ResolvedRate(BasePolicy):
    """u = J⁺(ẋ_d − k e): enough to drive the loop in these tests."""

    def _act(self, obs):
        fields = self.layout.unpack(obs)
        jac = self.kinematics.jacobian(fields.q)
        return np.linalg.pinv(jac) @ (fields.xdot_d - 2.0 * fields.e)


def _env(task="reach", realtime=False, **safety):
    connection = SimulatedConnection(realtime=realtime)
    return RealUREnv(task, connection, safety=SafetyLimits(**safety) if safety else None), connection


def test_whole_loop_reaches_the_paper_target_inside_the_safety_envelope():
    env, connection = _env(speed_scale=0.5)
    policy = ResolvedRate(env)
    obs, _ = env.reset(options={"q0": PAPER_Q0, "target": PAPER_TARGET})
    previous = np.zeros(6)
    for _ in range(env.max_steps):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        assert not terminated, info["safety"]
        assert np.all(np.abs(info["command"]) <= 0.5 * env.velocity_limits + 1e-12)
        assert np.all(np.abs(info["command"] - previous) <= env.safety_limits.max_joint_acceleration * env.dt + 1e-12)
        previous = info["command"]
        if truncated:
            break
    assert info["error_norm"] < 1e-3
    assert connection.commands_sent == env.max_steps
    env.close()
    assert connection.stop_calls >= 1


def test_same_spaces_as_the_simulated_env():
    import gymnasium as gym

    env, _ = _env()
    sim = gym.make("snac_gym/UR10Reach-v0")
    assert env.observation_space == sim.observation_space and env.action_space == sim.action_space
    assert env.obs_layout == sim.unwrapped.obs_layout


def _assert_at_rest(connection):
    assert connection.stopped and connection.stop_calls >= 1
    assert np.max(np.abs(connection.read_state()[1])) < 1e-3


def _assert_stopped(env, connection, info, terminated, match):
    assert terminated and match in info["safety"]
    assert connection.stopped and connection.stop_calls >= 1
    sent = connection.commands_sent
    with pytest.raises(RuntimeError, match="stopped"):
        env.step(np.zeros(6))
    assert connection.commands_sent == sent  # nothing after a stop


def test_leaving_the_task_box_stops_the_arm():
    x0 = SimulatedConnection(realtime=False).kinematics.forward(np.array(PAPER_Q0))
    env, connection = _env(
        box_low=tuple(x0 - 0.01), box_high=tuple(x0 + 0.01), speed_scale=1.0, max_joint_acceleration=40.0
    )
    env.reset(options={"q0": PAPER_Q0})
    for _ in range(200):
        _, _, terminated, _, info = env.step(np.array([0.5, 0, 0, 0, 0, 0]))
        if terminated:
            break
    _assert_stopped(env, connection, info, terminated, "task box")


def test_joint_limit_margin_stops_the_arm():
    q0 = np.array(PAPER_Q0)
    q0[2] = np.pi - 0.2  # elbow 0.2 rad from its URDF limit
    env, connection = _env(box_low=(-2, -2, -2), box_high=(2, 2, 2), max_joint_acceleration=40.0, speed_scale=1.0)
    env.reset(options={"q0": q0})
    for _ in range(100):
        _, _, terminated, _, info = env.step(np.array([0, 0, 1.0, 0, 0, 0]))
        if terminated:
            break
    _assert_stopped(env, connection, info, terminated, "elbow_joint")


@pytest.mark.parametrize("fault", [PROTECTIVE_STOP, EMERGENCY_STOP])
def test_controller_stops_end_the_episode(fault):
    env, connection = _env()
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.full(6, 0.01))
    connection.inject_fault(fault)
    _, _, terminated, _, info = env.step(np.full(6, 0.01))
    assert info["safety_state"] == fault
    _assert_stopped(env, connection, info, terminated, fault)
    with pytest.raises(RuntimeError, match=fault):
        env.reset()  # cleared on the pendant first


class _RefusingConnection(SimulatedConnection):
    """A controller that refuses the command in flight when a stop (or, with ``always``, anything) paused its
    program before the host read the stop: what ur_rtde's ``speedJ`` returning False looks like."""

    def __init__(self, always: bool = False) -> None:
        super().__init__(realtime=False)
        self.always = always

    def command(self, velocities: np.ndarray) -> None:
        if self.always or self.safety_state() != NORMAL:
            raise ConnectionFailure("the arm at sim rejected speedJ (connection lost or program stopped)")
        super().command(velocities)


@pytest.mark.parametrize("fault", [PROTECTIVE_STOP, EMERGENCY_STOP])
def test_a_stop_first_seen_as_a_refused_command_ends_the_episode_as_a_controller_stop(fault):
    connection = _RefusingConnection()
    env = RealUREnv("reach", connection)
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.full(6, 0.01))
    connection.inject_fault(fault)
    obs, _, terminated, _, info = env.step(np.full(6, 0.01))
    assert info["safety_state"] == fault and info["safety"] == f"controller reports {fault}"
    np.testing.assert_array_equal(info["command"], np.zeros(6))  # refused: logged as not sent
    _assert_stopped(env, connection, info, terminated, fault)
    with pytest.raises(RuntimeError, match=fault):
        env.reset()


class _LateReportConnection(SimulatedConnection):
    """A controller that refuses the command at once when a stop pauses its program, while its state
    packages report the stop only from the ``late``-th read on (the first package left before the stop)."""

    def __init__(self, late: int) -> None:
        super().__init__(realtime=False)
        self.late, self.reads_since_fault = late, 0

    def command(self, velocities: np.ndarray) -> None:
        if self._fault != NORMAL:
            raise ConnectionFailure("the arm at sim rejected speedJ (connection lost or program stopped)")
        super().command(velocities)

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        self.reads_since_fault += self._fault != NORMAL
        return super().read_state()

    def safety_state(self) -> str:
        return self._fault if self.reads_since_fault >= self.late else NORMAL


@pytest.mark.parametrize("fault", [PROTECTIVE_STOP, EMERGENCY_STOP])
def test_a_refusal_read_before_its_stop_shows_waits_for_the_package_that_shows_it(fault):
    connection = _LateReportConnection(late=3)
    env = RealUREnv("reach", connection)
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.full(6, 0.01))
    connection.inject_fault(fault)
    _, _, terminated, _, info = env.step(np.full(6, 0.01))
    assert connection.reads_since_fault == 3  # read again until the stop showed, not beyond
    assert info["safety_state"] == fault and info["safety"] == f"controller reports {fault}"
    _assert_stopped(env, connection, info, terminated, fault)


def test_a_refused_command_without_a_reported_stop_is_a_lost_link():
    connection = _RefusingConnection(always=True)
    env = RealUREnv("reach", connection)
    env.reset(options={"q0": PAPER_Q0})
    with pytest.raises(ConnectionFailure, match="rejected speedJ"):
        env.step(np.full(6, 0.01))
    assert connection.stopped and "rejected speedJ" in env.stop_reason


def test_missed_deadlines_stop_the_arm():
    env, connection = _env(max_missed_deadlines=3)
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.zeros(6))
    for k in range(3):
        time.sleep(2.5 * env.dt)  # a policy that takes 2.5 periods
        _, _, terminated, _, info = env.step(np.zeros(6))
        assert terminated == (k == 2)
    _assert_stopped(env, connection, info, terminated, "missed its 8.0 ms deadline in 3 of the last 3 periods")


def test_one_late_period_is_tolerated():
    env, _ = _env(max_missed_deadlines=3)
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.zeros(6))
    time.sleep(2.5 * env.dt)
    env.step(np.zeros(6))
    _, _, terminated, _, _ = env.step(np.zeros(6))
    assert not terminated


@pytest.mark.parametrize("error", [KeyboardInterrupt, ConnectionFailure, ZeroDivisionError])
def test_any_exception_in_the_loop_stops_the_arm(monkeypatch, error):
    env, connection = _env()
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.full(6, 0.05))

    def fail(_start):
        raise error("boom")

    monkeypatch.setattr(connection, "end_period", fail)
    with pytest.raises(error):
        env.step(np.full(6, 0.05))
    assert connection.stopped and env.stop_reason == f"{error.__name__} during step: boom"


def test_close_stops_the_arm():
    env, connection = _env()
    env.reset(options={"q0": PAPER_Q0})
    env.step(np.full(6, 0.05))
    env.close()
    assert connection.stop_calls >= 1 and connection.sim.client == -1


@pytest.mark.parametrize("action", [[np.nan, 0, 0, 0, 0, 0], [0.1] * 5, "fast"])
def test_a_bad_action_stops_the_moving_arm_and_ends_the_episode(action):
    env, connection = _env(speed_scale=1.0)
    env.reset(options={"q0": PAPER_Q0})
    for _ in range(20):
        env.step(np.full(6, 0.1))
    sent = connection.commands_sent
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    assert connection.commands_sent == sent  # the bad command itself never reached the arm
    assert env.stop_reason.startswith("ValueError during step: action")
    _assert_at_rest(connection)
    with pytest.raises(RuntimeError, match="stopped"):
        env.step(np.zeros(6))


def test_dry_run_sends_nothing_and_records_what_it_would_send():
    inner = SimulatedConnection(realtime=False)  # parked at θ0, where the (real) arm happens to be
    lines = []
    connection = DryRunConnection(inner, echo=lines.append)
    env = RealUREnv("reach", connection)
    obs, _ = env.reset(options={"q0": PAPER_Q0})
    policy = ResolvedRate(env)
    for _ in range(3):
        obs, *_ = env.step(policy.act(obs))
    assert inner.commands_sent == 0 and len(connection.sent) == 3
    assert lines[0].startswith("would moveJ") and lines[1].startswith("would send speedJ")
    # the arm did not move: the simulated motors hold it against gravity to ~1e-5 rad
    np.testing.assert_allclose(obs[:6], PAPER_Q0, atol=1e-4)


def test_loop_period_and_jitter_are_measured_at_125_hz():
    env, _ = _env(
        realtime=True, max_missed_deadlines=10**5, deadline_window=10**5, max_period=10.0
    )  # a loaded CI machine may be late
    env.reset(options={"q0": PAPER_Q0})
    for _ in range(63):  # half a second
        env.step(np.zeros(6))
    timing = env.timing()
    assert len(env.periods) == 63  # one per step: from one period start to the next
    # waitPeriod never returns early: each period lasts at least dt (jitter figures: README)
    assert timing["period_ms_p50"] >= 8.0 * 0.999
    assert set(timing) >= {"period_ms_mean", "period_ms_std", "period_ms_p99", "jitter_ms_max", "late_periods"}


def test_rtde_connection_fails_fast_on_a_closed_loopback_port(monkeypatch):
    # 127.0.0.2: the emulator tests may be listening on 127.0.0.1:30004 at the same time
    monkeypatch.setattr(connections, "require_installed", lambda *args: None)  # the port is probed without ur_rtde
    start = time.monotonic()
    with pytest.raises(ConnectionFailure, match="127.0.0.2:30004 refused") as excinfo:
        URRTDEConnection("127.0.0.2", connect_timeout=2.0)
    assert time.monotonic() - start < 5.0
    assert "\n" not in str(excinfo.value)


def test_safety_limits_validate_their_arguments():
    with pytest.raises(ValueError, match="speed_scale"):
        SafetyLimits(speed_scale=1.5)
    with pytest.raises(ValueError, match="task box"):
        SafetyLimits(box_low=(0, 0, 0), box_high=(0, 1, 1))


@pytest.mark.slow(seconds=4)
def test_real_run_writes_the_demo_outputs_plus_loop_timing(tmp_path):
    from snac_gym.apps.demo import run_demo
    from snac_gym.apps.real import run_real_episode

    # a loaded CI machine may be late now and then: the deadline rule has its own tests above
    said: list[str] = []
    result = run_real_episode(
        task="reach",
        controller="dls",
        out_dir=tmp_path / "real",
        connection="sim",
        steps=60,
        safety=SafetyLimits(max_missed_deadlines=10**5, deadline_window=10**5, max_period=10.0),
        progress=said.append,
    )
    assert said == [  # every kernel cached: no compile to announce
        "real: the control loop starts: 60 periods of 8 ms (0.48 s)",
        f"real: drawing 6 figures into {tmp_path / 'real'}/",
    ]
    demo = run_demo(task="reach", controller="dls", out_dir=tmp_path / "demo", steps=60)
    real_log, demo_log = result.demo.log, demo.log
    assert list(real_log.columns) == list(demo_log.columns) and len(real_log) == 60
    real_files = {p.name for p in (tmp_path / "real").iterdir()}
    demo_files = {p.name for p in (tmp_path / "demo").iterdir()}
    assert demo_files <= real_files
    assert {"reach_dls_timing.csv", "reach_dls_timing.png", "reach_dls_real.json"} <= real_files
    assert {p.name for p in result.files} == real_files  # every file it wrote, and the summary says how many
    assert f"  wrote {len(real_files)} files to {tmp_path / 'real'}" in result.summary().splitlines()
    assert result.timing["period_ms_p50"] >= 8.0 * 0.999 and result.stop_reason is None
    np.testing.assert_allclose(real_log.loc[0, [f"q_{j}" for j in range(6)]], PAPER_Q0, atol=1e-12)


def test_real_command_with_nothing_listening_fails_in_one_line_and_leaves_no_folder(tmp_path):
    import subprocess
    import sys

    (tmp_path / "kept").mkdir()
    for out in ("new/run", "kept"):  # the folders the run made are removed again; one that was there stays
        start = time.monotonic()
        done = subprocess.run(
            [sys.executable, "-m", "snac_gym.apps.cli", "real", "--host", "127.0.0.2", "--out", out],
            capture_output=True,
            text=True,
            timeout=30,
            cwd=tmp_path,
        )
        assert time.monotonic() - start < 10.0
        assert done.stdout == "" and done.stderr.strip().count("\n") == 0
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["kept"]
    if importlib.util.find_spec("rtde_receive") is None:  # the Python 3.13 variant: no ur_rtde wheel
        assert done.returncode == 2
        assert done.stderr == "error: --connection rtde (ur_rtde) needs the 'real' extra: pip install -e \".[real]\"\n"
    else:
        assert done.returncode == 1
        assert "127.0.0.2:30004 refused" in done.stderr


def test_a_missing_ur_rtde_is_named_before_the_controller_is_sought(monkeypatch):
    """ur_rtde runs in the client process only; without it, the connection says which extra to install, not that
    the controller cannot be reached (as it did, probing first) or that the client died on its import."""
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "rtde_receive" else real_find_spec(name, *a)
    )
    monkeypatch.setattr(connections, "probe_port", lambda *args: pytest.fail("probed a port without ur_rtde"))
    with pytest.raises(MissingExtraError, match=r"^--connection rtde \(ur_rtde\) needs the 'real' extra: pip install"):
        URRTDEConnection("127.0.0.2", connect_timeout=2.0)


def test_dry_run_command_on_the_simulated_connection_prints_what_it_would_send(tmp_path):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    outcome = CliRunner().invoke(
        app,
        [
            "real",
            "--connection",
            "sim",
            "--dry-run",
            "--steps",
            "5",
            "--controller",
            "dls",
            "--no-plots",
            "--out",
            str(tmp_path),
        ],  # fmt: skip
    )
    assert outcome.exit_code == 0, outcome.output
    assert outcome.output.count("would send speedJ") == 5
    assert "dry run: 5 commands computed, none sent" in outcome.output
    assert (tmp_path / "reach_dls_log.parquet").is_file() and not list(tmp_path.glob("*.png"))  # --no-plots


def test_connection_dropped_mid_episode_is_one_line_and_the_arm_is_stopped(monkeypatch, tmp_path, timing_rules_off):
    from typer.testing import CliRunner

    import snac_gym.apps.real as real_run
    from snac_gym.apps.cli import app

    connection = SimulatedConnection(realtime=False)
    reads = {"count": 0}
    original = connection.read_state

    def flaky_read():
        reads["count"] += 1
        if reads["count"] > 20:
            raise ConnectionFailure("connection to the arm at 10.0.0.2 was lost")
        return original()

    monkeypatch.setattr(connection, "read_state", flaky_read)
    monkeypatch.setattr(real_run, "make_connection", lambda *args, **kwargs: connection)
    outcome = CliRunner().invoke(app, ["real", "--host", "10.0.0.2", "--controller", "dls", "--out", str(tmp_path)])
    assert outcome.exit_code == 1
    assert outcome.output.strip().splitlines() == [  # when the arm started to move, then how it ended
        "real: the control loop starts: 1875 periods of 8 ms (15 s)",
        f"error: connection to the arm at 10.0.0.2 was lost; the log so far is in {tmp_path}/",
    ]
    assert connection.stopped and connection.stop_calls >= 1
    # the log so far is written: a lost link is a way out like any other
    summary = json.loads((tmp_path / "reach_dls_real.json").read_text())
    assert summary["ended"] == "link lost" and "was lost" in summary["reason"]
    assert len(pd.read_parquet(tmp_path / "reach_dls_log.parquet")) >= 15
