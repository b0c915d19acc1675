"""Hardware in the loop without a robot: the real ur_rtde client against the emulated controller.

Every test drives ``URRTDEConnection`` (ur_rtde's ``RTDEReceiveInterface`` and
``RTDEControlInterface``: dashboard, script upload, register handshake, speedJ) against
:class:`~snac_gym.real.emulator.process.EmulatorProcess`, injects a fault in the controller,
and checks what the controller saw: the arm at rest, and no ``speedJ`` after the stop.

ur_rtde connects to the fixed ports 29999/30003/30004, so one emulator is shared by the tests of
this module (reset between tests) and a concurrent run waits for the ports (``bind_timeout``).
Timing bounds are loose: the machine may be shared.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from _loopback import emulator_host

pytest.importorskip("rtde_control")
#: These run the real ur_rtde client against the emulator in real time: the README's test command
#: runs them on their own, after the parallel run, so that no other test competes for the CPU.
pytestmark = pytest.mark.realtime

from snac_gym.model.kinematics import Kinematics  # noqa: E402
from snac_gym.model.ur_models import flange_transform  # noqa: E402
from snac_gym.real import ConnectionFailure, RealUREnv, SafetyLimits, URRTDEConnection  # noqa: E402
from snac_gym.real.emulator.arm import matrix_to_pose  # noqa: E402
from snac_gym.real.emulator.process import EmulatorProcess  # noqa: E402
from snac_gym.sampling import nominal_configuration  # noqa: E402

HOST = emulator_host()
#: Timing rules loosened for the tests that are not about timing: the host may be shared.
LOOSE_TIMING = {"max_stale_periods": 25, "max_period": 0.5, "max_missed_deadlines": 25}
#: Longest delay (s) between sending a command and the controller stamping it, on a busy host.
DELIVERY = 0.1
#: A command that moves the end effector (base joint) at the safety layer's speed bound.
SWEEP = np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture
def connection(emu: EmulatorProcess) -> Iterator[URRTDEConnection]:
    """The ur_rtde connection; its watchdog at 25 periods (200 ms) so that a busy host does not trip it."""
    arm = URRTDEConnection(HOST, acceleration=4.0, watchdog_periods=25)
    yield arm
    arm.close()


@pytest.fixture
def default_connection(emu: EmulatorProcess) -> Iterator[URRTDEConnection]:
    """The ur_rtde connection as ``snac-gym real`` builds it: the watchdog at 5 periods (40 ms)."""
    arm = URRTDEConnection(HOST, acceleration=4.0)
    yield arm
    arm.close()


def _env(connection: URRTDEConnection, steps: int = 400, **safety: object) -> RealUREnv:
    limits = {**LOOSE_TIMING, **safety}
    return RealUREnv("reach", connection, safety=SafetyLimits(**limits), max_steps=steps)


def _run_until_stop(
    env: RealUREnv,
    fault: Callable[[], None] | None,
    fault_step: int = 25,
    steps: int = 300,
    action: np.ndarray = SWEEP,
    q0: np.ndarray | None = None,
) -> tuple[float, float, dict]:
    """Stream ``action``, inject ``fault`` at ``fault_step``, step until the episode ends.

    Returns the fault's monotonic time, the time the ending step returned, and its info.
    """
    env.reset(options={"target": [-0.7, 0.2, 0.4], "q0": q0})
    t_fault = float("inf")
    for k in range(steps):
        if k == fault_step and fault is not None:
            t_fault = time.monotonic()
            fault()
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return t_fault, time.monotonic(), info
    raise AssertionError(f"the episode did not end in {steps} steps")


def _assert_stopped_and_silent(emu: EmulatorProcess, since: float) -> None:
    """The emulated arm comes to rest, and no speedJ sent after ``since`` reached the controller.

    The controller stamps a package when its reader thread gets it: a command sent just before
    ``since`` may be stamped up to a scheduling delay later, hence :data:`DELIVERY`.
    """
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and max(map(abs, emu.status()["qd"])) > 1e-9:
        time.sleep(0.02)
    assert max(map(abs, emu.status()["qd"])) <= 1e-9, emu.status()
    assert emu.speed_commands_after(since + DELIVERY) == []


# ---------------------------------------------------------------------------- the client itself


def test_ur_rtde_connects_uploads_its_script_and_streams_speedj(emu, connection):
    status = emu.status()  # the constructor uploaded ur_rtde's control script; no watchdog yet
    assert status["protocol_errors"] == [] and status["programs"] == ["rtde_control"]
    assert status["program_running"] and status["watchdog"] is None
    q, qd = connection.read_state()
    np.testing.assert_allclose(q, nominal_configuration(connection.kinematics), atol=1e-12)
    # The TCP pose the controller computes from its DH table is the project's f(q), base frame.
    np.testing.assert_allclose(connection.reported_tcp_position(), connection.kinematics.forward(q), atol=1e-9)
    assert connection.speed_scaling() == 1.0
    for _ in range(60):
        start = connection.start_period()
        connection.command(np.full(6, 0.05))
        connection.end_period(start)
    status = emu.status()
    assert status["program_running"] and status["programs"] == ["rtde_control"]
    assert status["watchdog"] == [125.0 / 25, "input_int_register_0"]  # armed by the first command
    np.testing.assert_allclose(connection.read_state()[1], 0.05, atol=1e-9)
    connection.stop()  # speedStop: the script's handshake returns once the arm is at rest
    assert max(map(abs, emu.status()["qd"])) == 0.0
    assert status["unsupported_commands"] == [] and emu.status()["protocol_errors"] == []


def test_the_emulators_dh_model_matches_the_projects_urdf_kinematics():
    rng = np.random.default_rng(0)
    for robot in ("ur3", "ur5", "ur10"):
        kinematics = Kinematics(robot)
        for q in rng.uniform(-np.pi, np.pi, size=(20, 6)):
            np.testing.assert_allclose(flange_transform(robot, q)[:3, 3], kinematics.forward(q), atol=1e-9)
    pose = matrix_to_pose(flange_transform("ur10", nominal_configuration(Kinematics("ur10"))))
    assert pose.shape == (6,) and np.linalg.norm(pose[3:]) <= np.pi + 1e-9


def test_moveJ_to_the_start_pose_runs_the_blocking_handshake(emu, connection):
    env = _env(connection)
    q0 = nominal_configuration(connection.kinematics) + np.array([0.1, -0.05, 0.05, 0.0, 0.0, 0.0])
    env.reset(options={"q0": q0, "target": [-0.7, 0.2, 0.4]})
    np.testing.assert_allclose(emu.status()["q"], q0, atol=1e-9)
    assert [c for _, c, _ in emu.commands_since(0.0) if c not in (0, 9)] == [15, 1]  # speedStop, moveJ
    env.close()


# ---------------------------------------------------------------------------- the safety table


@pytest.mark.parametrize(
    ("fault", "state"), [("protective_stop", "protective_stop"), ("emergency_stop", "emergency_stop")]
)
def test_a_controller_stop_ends_the_episode_and_nothing_is_sent_after_it(emu, connection, fault, state):
    env = _env(connection)
    stops_before = connection.stop_calls
    t_fault, t_end, info = _run_until_stop(env, getattr(emu, fault))
    assert info["safety_state"] == state and info["safety"] == f"controller reports {state}"
    assert connection.stop_calls > stops_before  # speedStop was called (the paused script answers False)
    # at most the command in flight when the fault hit (the host learns of it from the next package)
    assert len(emu.speed_commands_after(t_fault)) <= 5  # sent before the host could see the stop
    _assert_stopped_and_silent(emu, t_end)
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(SWEEP)
    with pytest.raises(RuntimeError, match=state):  # a stopped controller is not restarted by reset
        env.reset(options={"target": [-0.7, 0.2, 0.4]})
    assert emu.speed_commands_after(t_end + DELIVERY) == []


def test_a_dropped_link_is_seen_within_one_period_and_the_watchdog_stops_the_arm(emu, connection):
    env = _env(connection)
    env.reset(options={"target": [-0.7, 0.2, 0.4]})
    for _ in range(25):
        env.step(SWEEP)
    t_drop = time.monotonic()
    emu.drop_connection()
    # Seen as a closed link, or as ur_rtde's own reconnect starting, which ends the client.
    with pytest.raises(ConnectionFailure, match="was lost|began to reconnect by itself"):
        for _ in range(3):
            env.step(SWEEP)
    assert "ConnectionFailure" in env.stop_reason and connection.failure is not None
    assert len(env.periods) <= 27  # the step after the drop raised (one period)
    _assert_stopped_and_silent(emu, t_drop)
    events = emu.status()["events"]
    assert any(e.startswith("watchdog expired") for e in events), events
    emu.clear_faults()


def test_the_watchdog_stops_the_arm_when_the_host_goes_silent(emu, default_connection):
    env = _env(default_connection, max_period=0.04)
    env.reset(options={"target": [-0.7, 0.2, 0.4]})
    for _ in range(25):
        env.step(SWEEP)
    assert max(map(abs, emu.status()["qd"])) > 0.1
    t_silent = time.monotonic()
    time.sleep(0.4)  # the host stalls: no command for 50 periods
    status = emu.status()
    assert max(map(abs, status["qd"])) == 0.0 and not status["program_running"]
    assert any(e.startswith("watchdog expired") for e in status["events"])
    _, _, terminated, _, info = env.step(SWEEP)  # the host wakes up: its stall rule stops it, nothing sent
    assert terminated and info["safety"].startswith("control loop stalled") and "command not sent" in info["safety"]
    assert emu.speed_commands_after(t_silent + DELIVERY) == []


def test_an_injected_watchdog_expiry_stops_the_program_and_the_stream(emu, connection):
    env = _env(connection)
    env.reset(options={"target": [-0.7, 0.2, 0.4]})
    for _ in range(25):
        env.step(SWEEP)
    emu.expire_watchdog()
    deadline = time.monotonic() + 2.0
    while emu.status()["program_running"] and time.monotonic() < deadline:
        time.sleep(0.005)
    status = emu.status()
    assert not status["program_running"] and any(e.startswith("watchdog expired") for e in status["events"])
    with pytest.raises(ConnectionFailure, match="rejected speedJ"):
        for _ in range(10):
            env.step(SWEEP)
    assert "rejected speedJ" in env.stop_reason
    _assert_stopped_and_silent(emu, time.monotonic())


@pytest.mark.parametrize(("extra", "rule"), [(0.1, "control loop stalled"), (0.014, "control loop missed its 8.0 ms")])
def test_a_late_host_loop_stops_the_arm(emu, default_connection, extra, rule):
    connection = default_connection
    env = _env(connection, max_period=0.04, max_missed_deadlines=3, deadline_window=25)
    env.reset(options={"target": [-0.7, 0.2, 0.4]})
    for k in range(200):
        if k >= 20:
            time.sleep(extra)  # a slow policy: every period from here on is late
        _, _, terminated, _, info = env.step(SWEEP)
        if terminated:
            break
    assert info["safety"].startswith(rule), info["safety"]
    _assert_stopped_and_silent(emu, time.monotonic())


def test_the_workspace_box_stops_the_arm(emu, connection):
    x0 = connection.kinematics.forward(nominal_configuration(connection.kinematics))
    env = _env(connection, box_low=tuple(x0 - 0.02), box_high=tuple(x0 + 0.02))
    _, t_end, info = _run_until_stop(env, None)
    assert info["safety"].startswith("end effector")
    _assert_stopped_and_silent(emu, t_end)


def test_the_joint_margin_stops_the_arm(emu, connection):
    kinematics = connection.kinematics
    q0 = nominal_configuration(kinematics)
    q0[5] = kinematics.lower_limits[5] + 0.1 + 0.03  # wrist 3, 0.03 rad short of the 0.1 rad margin
    connection.move_speed = 3.0  # the 4.5 rad moveJ there at 3 rad/s (the default 0.3 takes 15 s); wrist 3 allows 3.2
    env = _env(connection)
    _, t_end, info = _run_until_stop(env, None, action=np.array([0, 0, 0, 0, 0, -0.4]), q0=q0)
    assert info["safety"].startswith("joint 5"), info["safety"]
    _assert_stopped_and_silent(emu, t_end)


@pytest.mark.parametrize(("fault", "rule"), [("stale_data", "stale joint state"), ("nonfinite_state", "non-finite")])
def test_stale_or_non_finite_controller_data_stops_the_arm(emu, connection, fault, rule):
    # The host cannot see the arm come to rest in frozen data: its wait after speedStop runs out
    # (3 s by default), which is not what is tested here.
    connection.rest_timeout = 0.5
    env = _env(connection, max_stale_periods=3)
    t_fault, t_end, info = _run_until_stop(env, getattr(emu, fault))
    assert info["safety"].startswith(rule), info["safety"]
    _assert_stopped_and_silent(emu, t_end)
    assert len(emu.speed_commands_after(t_fault)) <= 5  # detected within a few periods of the fault
    emu.clear_faults()


def test_a_latency_spike_freezes_the_data_and_the_stale_rule_stops_the_arm(emu, connection):
    env = _env(connection, max_stale_periods=3)
    _, t_end, info = _run_until_stop(env, lambda: emu.latency_spike(0.2))
    assert info["safety"].startswith("stale joint state"), info["safety"]
    _assert_stopped_and_silent(emu, t_end)


def test_commands_reach_the_controller_speed_clipped_and_rate_limited(emu, connection):
    env = _env(connection, speed_scale=0.25, max_joint_acceleration=2.0, box_low=(-2, -2, -2), box_high=(2, 2, 2))
    since = time.monotonic()
    env.reset(options={"target": [-0.7, 0.2, 0.4]})
    for _ in range(80):
        env.step(connection.kinematics.velocity_limits)  # the policy asks for full speed on every joint
    env.close()
    sent = np.array(
        [[c[2][f"input_double_register_{j}"] for j in range(6)] for c in emu.commands_since(since) if c[1] == 9]
    )
    bound = 0.25 * np.radians([120, 120, 180, 180, 180, 180])  # the UR10's datasheet, below its URDF's speeds
    assert len(sent) >= 79 and np.all(np.abs(sent) <= bound + 1e-12)
    assert np.all(np.abs(np.diff(sent, axis=0)) <= 2.0 * env.dt + 1e-12)
    np.testing.assert_allclose(sent[-1], bound)  # the cap was reached, so it did bind


# ---------------------------------------------------------------------------- FK check, speed slider


def test_a_wrong_tool_offset_is_refused_before_the_arm_moves(emu, connection):
    emu.set_tcp_offset([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])  # a 5 cm tool the model does not know
    env = _env(connection)
    with pytest.raises(RuntimeError, match=r"TCP mismatch: .*\(50.0 mm apart"):
        env.reset(options={"target": [-0.7, 0.2, 0.4]})
    assert emu.speed_commands_after(0.0) == []


def test_a_tcp_mismatch_mid_episode_stops_the_arm(emu, connection):
    env = _env(connection)
    t_fault, t_end, info = _run_until_stop(env, lambda: emu.set_tcp_offset([0.01, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert info["safety"].startswith("TCP mismatch") and "10.0 mm apart" in info["safety"]
    _assert_stopped_and_silent(emu, t_end)
    assert len(emu.speed_commands_after(t_fault)) <= 5  # sent before the host read the mismatching pose


def test_a_speed_slider_below_100_percent_is_reported_and_not_a_fault(emu, connection):
    emu.set_speed_scaling(0.5)
    env = _env(connection, steps=120)
    _, info = env.reset(options={"target": [-0.7, 0.2, 0.4]})
    assert info["speed_scaling"] == 0.5
    for _ in range(120):
        _, _, terminated, truncated, info = env.step(SWEEP)
        assert not terminated, info["safety"]
    assert truncated and info["speed_scaling"] == 0.5 and env.timing()["speed_scaling_min"] == 0.5
    # the controller ran the command at half speed: the arm trails u by the slider, by design
    np.testing.assert_allclose(emu.status()["qd"], 0.0, atol=1e-12)  # stopped at truncation
    assert env.stop_reason is None


def test_the_emulator_refuses_bad_fault_arguments(emu):
    with pytest.raises(ValueError, match="speed scaling must be in"):
        emu.set_speed_scaling(1.5)
    with pytest.raises(ValueError, match="non-negative number of seconds"):
        emu.latency_spike(-1.0)
    with pytest.raises(ValueError, match="6 finite numbers"):
        emu.set_tcp_offset([0.0, 0.0])
    with pytest.raises(AttributeError, match="no remote method"):
        emu.call("close")


# ---------------------------------------------------------------------------- the whole command


@pytest.mark.realtime(seconds=7)  # about this long here: run first (conftest.py)
def test_snac_gym_real_against_the_emulator_reaches_within_1mm_with_the_usual_outputs(emu, tmp_path):
    from snac_gym.apps.real import run_real_episode

    # The run keeps the default 40 ms stall limit, as `snac-gym real` does (a shared host that stalls
    # past it gets the test a rerun: see HOST_TIMING_STOPS in conftest.py). The LQR law reaches
    # within 1 mm in 2.6 s of motion (SNAC in 10 s; tests/realtime/test_real_isolation.py runs SNAC
    # through the same path): a 4 s episode.
    out = tmp_path / "run"
    result = run_real_episode(
        task="reach", controller="lqr", out_dir=out, connection="rtde", host=HOST, steps=500,
        safety=SafetyLimits(max_stale_periods=10),
    )  # fmt: skip
    assert result.stop_reason is None, result.stop_reason
    final_error = float(np.linalg.norm(result.demo.log[["e_0", "e_1", "e_2"]].to_numpy()[-1]))
    assert final_error < 1e-3
    names = {p.name for p in out.iterdir()}
    assert {
        "reach_lqr_log.parquet",
        "reach_lqr_figure3.png",
        "reach_lqr_timing.csv",
        "reach_lqr_timing.png",
    } <= names
    assert result.timing["speed_scaling_min"] == 1.0 and 7.5 < result.timing["period_ms_p50"] < 8.5
    status = emu.status()
    assert status["protocol_errors"] == [] and status["unsupported_commands"] == []
    assert max(map(abs, status["qd"])) == 0.0  # stopped at the end


def test_emulate_ur_command_serves_on_free_ports_and_refuses_bad_flags():
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    command = ["emulate-ur", "--port-base", "0", "--duration", "0.3"]
    outcome = CliRunner().invoke(app, command + ["--protective-stop-at", "1", "--latency-spike", "2,0.1"])
    assert outcome.exit_code == 0, outcome.output
    assert "emulated UR controller (cb, 125 Hz) on 127.0.0.1: dashboard" in outcome.output
    for flags, message in [
        (["--tcp-offset", "0.1,0.2"], "--tcp-offset needs 3 or 6 numbers"),
        (["--latency-spike", "1"], "--latency-spike (AT,SECONDS) needs 2 numbers"),
        (["--speed-scaling", "0"], "--speed-scaling must be in (0, 1]"),
        (["--series", "x"], "--series must be one of cb, e, got 'x'"),
        (["--series", "e"], "--series e is the e-Series' 500 Hz; the UR10 is a CB3 arm"),
        (["--port-base", "80"], "--port-base must be 0"),
    ]:
        outcome = CliRunner().invoke(app, command + flags)
        assert outcome.exit_code == 2 and message in outcome.output, (flags, outcome.output)
