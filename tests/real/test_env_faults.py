"""The real-robot env under faults: every way out of an episode stops the arm.

The faults are injected by :class:`FaultyConnection`, a wrapper around the simulated connection that
corrupts the state, freezes its timestamp, delays periods or keeps the arm moving, while
counting what reached the arm.
"""

import json
import os
import signal
import threading
import time
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from snac_gym.policies import register_policy
from snac_gym.policies.base import BasePolicy
from snac_gym.real import (
    EMERGENCY_STOP,
    NORMAL,
    PROTECTIVE_STOP,
    ConnectionFailure,
    RealUREnv,
    SafetyLimits,
    SimulatedConnection,
)
from snac_gym.real.recovery import RecoveryLimits
from snac_gym.references import PAPER_Q0


class FaultyConnection:
    """A :class:`SimulatedConnection` whose state and timing can be broken on purpose.

    Attributes:
        corrupt_state: ``None``, ``"nan_q"`` or ``"inf_qdot"``: what :meth:`read_state` returns.
        freeze_timestamp: Repeat the last state timestamp from now on.
        delays: Extra seconds added to the next periods (consumed one per period).
        keep_moving: The arm ignores ``stop`` (the controller failed to decelerate it).
    """

    def __init__(self) -> None:
        self.inner = SimulatedConnection(realtime=False)
        self.kinematics, self.dt = self.inner.kinematics, self.inner.dt
        self.corrupt_state: str | None = None
        self.freeze_timestamp = False
        self.delays: list[float] = []
        self.keep_moving = False
        self.moves = 0
        self._frozen: float | None = None

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def read_state(self):
        q, qdot = self.inner.read_state()
        if self.corrupt_state == "nan_q":
            q[1] = np.nan
        elif self.corrupt_state == "inf_qdot":
            qdot[4] = np.inf
        elif self.keep_moving:
            qdot[0] = 0.2
        return q, qdot

    def state_timestamp(self):
        if self.freeze_timestamp:
            self._frozen = self.inner.state_timestamp() if self._frozen is None else self._frozen
            return self._frozen
        return self.inner.state_timestamp()

    def end_period(self, period_start):
        self.inner.end_period(period_start)
        if self.delays:
            time.sleep(self.delays.pop(0))

    def move_to(self, q):
        self.moves += 1
        self.inner.move_to(q)

    def stop(self):
        self.inner.stop()


def _env(**safety):
    connection = FaultyConnection()
    env = RealUREnv("reach", connection, safety=SafetyLimits(speed_scale=1.0, max_joint_acceleration=40.0, **safety))
    env.reset(options={"q0": PAPER_Q0})
    return env, connection


def _drive(env, steps, u=0.1):
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(np.full(6, u))
        if terminated or truncated:
            break
    return terminated, truncated, info


def _assert_stopped_at_rest(env, connection, match=None):
    assert connection.inner.stopped and connection.inner.stop_calls >= 1
    assert np.max(np.abs(connection.inner.read_state()[1])) < 1e-3
    if match is not None:
        assert match in env.stop_reason
    sent = connection.inner.commands_sent
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(6))
    assert connection.inner.commands_sent == sent


@pytest.mark.parametrize(
    ("fault", "match"), [("nan_q", "non-finite joint state"), ("inf_qdot", "non-finite joint velocities")]
)
def test_non_finite_state_from_the_controller_stops_the_arm(fault, match):
    env, connection = _env()
    _drive(env, 20)
    connection.corrupt_state = fault
    terminated, _, info = _drive(env, 1)
    assert terminated and match in info["safety"]
    _assert_stopped_at_rest(env, connection, match)


def test_stale_state_stops_the_arm():
    env, connection = _env(max_stale_periods=3)
    _drive(env, 20)
    connection.freeze_timestamp = True
    steps = 0
    while True:
        steps += 1
        terminated, _, info = _drive(env, 1)
        if terminated:
            break
    assert steps == 4 and "stale joint state" in info["safety"]  # the first frozen read is still new
    _assert_stopped_at_rest(env, connection, "stale")


def test_truncation_stops_the_arm_and_brings_it_to_rest():
    env, connection = _env()
    env.max_steps = 30
    terminated, truncated, _ = _drive(env, 100)
    assert truncated and not terminated and env.stop_reason is None
    _assert_stopped_at_rest(env, connection)


def test_reset_without_q0_stops_a_moving_arm_before_the_next_episode():
    env, connection = _env()
    _drive(env, 40, u=0.3)
    assert np.max(np.abs(connection.inner.read_state()[1])) > 0.2  # moving when the episode is abandoned
    env.reset()
    assert np.max(np.abs(connection.inner.read_state()[1])) < 1e-3
    # the acceleration bound starts from rest again, and the arm really is at rest
    _, _, _, _, info = env.step(np.full(6, 3.0))
    np.testing.assert_allclose(np.abs(info["command"]), env.safety.step_bound)


def test_reset_refuses_an_unsafe_start_pose_before_moving_there():
    env, connection = _env()
    moves = connection.moves
    q0 = np.array(PAPER_Q0)
    q0[2] = np.pi - 0.05  # elbow within the 0.1 rad margin of its limit
    with pytest.raises(ValueError, match=r"options\['q0'\] is outside the safety limits: joint 2 \(elbow_joint\)"):
        env.reset(options={"q0": q0})
    assert connection.moves == moves
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(6))


def test_an_arm_that_does_not_come_to_rest_is_not_started():
    env, connection = _env()
    connection.keep_moving = True
    with pytest.raises(RuntimeError, match="still moving"):
        env.reset(options={"q0": PAPER_Q0})


def test_late_periods_that_are_not_consecutive_stop_the_arm():
    env, connection = _env(max_missed_deadlines=3, deadline_window=25)
    _drive(env, 5)
    connection.delays = [2.5 * env.dt, 2.5 * env.dt, 0.0] * 10  # two late periods of every three
    steps = 0
    while True:
        steps += 1
        terminated, _, info = _drive(env, 1)
        if terminated:
            break
    assert steps == 4 and "deadline in 3 of the last" in info["safety"]
    _assert_stopped_at_rest(env, connection)


def test_a_single_stall_stops_the_arm():
    env, connection = _env(max_period=0.04)
    _drive(env, 5)
    connection.delays = [0.1]
    terminated, _, info = _drive(env, 1)
    assert terminated and "stalled: one period took" in info["safety"]
    _assert_stopped_at_rest(env, connection)


class SendsSignal(BasePolicy):
    """Holds a small velocity and sends ``signum`` to its own process at step ``at``."""

    def __init__(self, env, signum: int = signal.SIGTERM, at: int = 30) -> None:
        super().__init__(env)
        self.signum, self.at, self.count = signum, at, 0

    def _act(self, obs):
        self.count += 1
        if self.count == self.at:
            os.kill(os.getpid(), self.signum)
        return np.full(6, 0.05)


@pytest.fixture
def signalling_run(monkeypatch):
    import snac_gym.apps.real as real_run

    connection = SimulatedConnection(realtime=False)
    speeds_after_stop = []
    stop = connection.stop

    def stop_and_record():
        stop()
        if connection.sim.client >= 0:
            speeds_after_stop.append(np.max(np.abs(connection.read_state()[1])))

    monkeypatch.setattr(connection, "stop", stop_and_record)
    monkeypatch.setattr(real_run, "make_connection", lambda *args, **kwargs: connection)
    register_policy("sends-signal", SendsSignal, overwrite=True)
    return connection, speeds_after_stop


@pytest.mark.parametrize(
    "signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1, signal.SIGUSR2]
)
def test_every_stop_signal_stops_the_arm_and_writes_the_log_so_far(signalling_run, tmp_path, signum):
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    previous = signal.getsignal(signum)
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(
            controller="sends-signal",
            out_dir=tmp_path,
            connection="sim",
            steps=200,
            policy_kwargs={"signum": signum},
            safety=SafetyLimits(max_period=10.0, deadline_slack=10.0),
        )
    assert excinfo.value.signum == signum
    assert signal.getsignal(signum) is previous  # the handlers are put back
    connection, speeds_after_stop = signalling_run
    assert connection.stopped and speeds_after_stop and max(speeds_after_stop) < 1e-3
    log = pd.read_parquet(tmp_path / "reach_sends-signal_log.parquet")
    assert len(log) == 29  # step 30's command was never sent
    assert log.attrs["interrupted"] == "TerminationSignal"
    summary = json.loads((tmp_path / "reach_sends-signal_real.json").read_text())
    assert summary["signal"] == signal.Signals(signum).name and summary["steps_logged"] == 29
    assert summary["ended"] == "interrupted"
    assert summary["stop_reason"] == "closed mid-episode"  # the signal came during the policy's act
    assert len(pd.read_csv(tmp_path / "reach_sends-signal_timing.csv")) == 29


def test_the_real_command_reports_a_signal_in_one_line(signalling_run, tmp_path, timing_rules_off):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    outcome = CliRunner().invoke(
        app, ["real", "--connection", "sim", "--controller", "sends-signal", "--out", str(tmp_path)]
    )
    assert outcome.exit_code == 128 + signal.SIGTERM
    assert outcome.output.strip().splitlines() == [  # when the arm started to move, then how it ended
        "real: the control loop starts: 1875 periods of 8 ms (15 s)",
        f"interrupted by SIGTERM: the arm was stopped; the log so far is in {tmp_path}/",
    ]
    assert signalling_run[0].stopped


#: What run_real_episode calls between connecting and the first period, as the names it holds them by; a signal
#: sent as each is called. "subprocess" is the stream log's writer start, after its header is on disk.
SETUP_STEPS = ["RealUREnv", "StepJournal", "subprocess", "frozen_gc", "warm_up", "make_policy"]


@pytest.mark.parametrize("step", SETUP_STEPS)
def test_a_signal_before_the_first_period_says_where_its_files_are_or_writes_none(
    signalling_run, tmp_path, monkeypatch, step
):
    """What the command says ("the log so far is in ..." or "nothing logged") is read off ``log_dir``: it must be set
    exactly when a file was written, wherever in the start the signal came, and the arm is stopped either way."""
    import subprocess

    import snac_gym.apps.real as real_run
    import snac_gym.real.journal as journal_module
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    def signalling(original):
        def call(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGTERM)
            return original(*args, **kwargs)

        return call

    if step == "subprocess":
        started = signalling(subprocess.Popen)
        monkeypatch.setattr(
            journal_module,
            "subprocess",
            SimpleNamespace(Popen=started, PIPE=subprocess.PIPE, TimeoutExpired=TimeoutError),
        )
    else:
        monkeypatch.setattr(real_run, step, signalling(getattr(real_run, step)))
    out = tmp_path / "out"
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(controller="dls", out_dir=out, connection="sim", steps=20)
    files = sorted(p.name for p in out.rglob("*") if p.is_file()) if out.exists() else []
    log_dir = getattr(excinfo.value, "log_dir", None)
    assert (log_dir is not None) == bool(files), (log_dir, files)
    if files:
        summary = json.loads((out / "reach_dls_real.json").read_text())
        assert summary["ended"] == "interrupted" and summary["steps_logged"] == 0
    assert signalling_run[0].stopped


def test_a_signal_as_the_finished_episodes_stream_log_closes_waits_for_the_outputs(
    signalling_run, tmp_path, monkeypatch
):
    """Closing the stream log waits for its writer process; a signal then (a Ctrl-C at the episode's end) is raised
    once the full log and summary are written, and says where they are."""
    import snac_gym.real.journal as journal_module
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    close = journal_module.StepJournal.close

    def close_signalled(journal):
        os.kill(os.getpid(), signal.SIGTERM)
        close(journal)

    monkeypatch.setattr(journal_module.StepJournal, "close", close_signalled)
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(controller="dls", out_dir=tmp_path, connection="sim", steps=20, plots=False)
    assert getattr(excinfo.value, "log_dir", None) == tmp_path
    assert len(pd.read_parquet(tmp_path / "reach_dls_log.parquet")) == 20
    assert not (tmp_path / "reach_dls_stream.csv").exists()  # replaced by the full log, as in a run not interrupted
    assert signalling_run[0].stopped


@pytest.mark.parametrize(
    ("signalled", "drawn"), [("close", 0), ("save_figure", 2)], ids=["as the stream log closes", "at the third figure"]
)
def test_a_signal_after_the_episode_cuts_only_the_figures(signalling_run, tmp_path, monkeypatch, signalled, drawn):
    """After the episode, a signal waits while the data is written (the log, its summary, the loop timing and
    real.json: a signal as the stream log closes, the last thing before them), then stops the figures at once
    instead of after all of them (seconds on a busy host), each figure whole or absent."""
    import snac_gym.apps.plots as plots_module
    import snac_gym.real.journal as journal_module
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    owner, name = (journal_module.StepJournal, "close") if signalled == "close" else (plots_module, "save_figure")
    original, calls = getattr(owner, name), []

    def signalling(*args, **kwargs):
        calls.append(1)
        if len(calls) == (1 if signalled == "close" else 3):
            os.kill(os.getpid(), signal.SIGTERM)
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, signalling)
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(controller="snac", out_dir=tmp_path, connection="sim", steps=30)
    assert excinfo.value.signum == signal.SIGTERM and getattr(excinfo.value, "log_dir", None) == tmp_path
    figures = ["path", "error", "joint_velocities", "cost", "figure3", "critic_weights", "optimality", "timing"]
    assert excinfo.value.kept == (
        f"the log and summary are complete in {tmp_path}/; {drawn} of {len(figures)} figures were drawn (each whole); "
        f"`snac-gym plot {tmp_path}/reach_snac_log.parquet` draws them all"
    )
    assert len(pd.read_parquet(tmp_path / "reach_snac_log.parquet")) == 30
    assert json.loads((tmp_path / "reach_snac_summary.json").read_text())["complete"] is True
    real = json.loads((tmp_path / "reach_snac_real.json").read_text())
    assert real["stop_reason"] is None and real["timing"]["periods"] == 30  # the finished run's record, whole
    assert len(pd.read_csv(tmp_path / "reach_snac_timing.csv")) == 30
    assert not (tmp_path / "reach_snac_stream.csv").exists()  # replaced by the full log
    pngs = sorted(p.name for p in tmp_path.iterdir() if ".png" in p.name)
    assert pngs == sorted(f"reach_snac_{figure}.png" for figure in figures[:drawn]), pngs  # no .partial either
    assert signalling_run[0].stopped


class SignalsTwice(SendsSignal):
    """Sends SIGTERM at step ``at``; its connection then sends SIGQUIT from inside the stop that follows."""

    sent = False

    def _act(self, obs):
        SignalsTwice.sent = self.count + 1 >= self.at
        return super()._act(obs)


def test_a_second_signal_does_not_cut_the_stop_path_or_the_log(signalling_run, tmp_path, monkeypatch):
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    connection, speeds_after_stop = signalling_run
    stop = connection.stop

    def stop_interrupted_again():
        if SignalsTwice.sent:
            os.kill(os.getpid(), signal.SIGQUIT)  # an impatient operator, mid-stop
        stop()

    monkeypatch.setattr(connection, "stop", stop_interrupted_again)
    register_policy("signals-twice", SignalsTwice, overwrite=True)
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(controller="signals-twice", out_dir=tmp_path, connection="sim", steps=200,
                         safety=SafetyLimits(max_period=10.0, deadline_slack=10.0))  # fmt: skip
    assert excinfo.value.signum == signal.SIGTERM  # the first signal is the one reported
    assert connection.stopped and speeds_after_stop and max(speeds_after_stop) < 1e-3  # the stop ran to rest
    assert len(pd.read_parquet(tmp_path / "reach_signals-twice_log.parquet")) == 29
    assert json.loads((tmp_path / "reach_signals-twice_real.json").read_text())["signal"] == "SIGTERM"


class Holds(SendsSignal):
    """Holds a small velocity and sends nothing: the episode runs to its end (:attr:`acted` counts its commands)."""

    acted = 0

    def _act(self, obs):
        Holds.acted += 1
        return np.full(6, 0.05)


def test_a_signal_in_the_last_periods_stop_still_leaves_the_arm_at_rest(signalling_run, tmp_path, monkeypatch):
    """The env stops the arm as the episode's last period ends; a first signal raised inside that stop cuts it, and
    the stop path that follows (the run's close) must still bring the arm to rest, with the log of every period
    before."""
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    connection, speeds_after_stop = signalling_run
    stop = connection.stop
    sent: list[int] = []

    def stop_signalled_first():
        if not sent and Holds.acted == 40:  # the stop that ends the last period, not the one before the first
            sent.append(signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            sum(range(100_000))  # the handler runs in here, before the stop has begun
        stop()

    monkeypatch.setattr(connection, "stop", stop_signalled_first)
    monkeypatch.setattr(Holds, "acted", 0)
    register_policy("holds", Holds, overwrite=True)
    with pytest.raises(TerminationSignal) as excinfo:
        run_real_episode(controller="holds", out_dir=tmp_path, connection="sim", steps=40,
                         safety=SafetyLimits(max_period=10.0, deadline_slack=10.0))  # fmt: skip
    assert sent and excinfo.value.signum == signal.SIGTERM
    assert connection.stopped and speeds_after_stop and max(speeds_after_stop) < 1e-3  # the stop ran to rest
    assert len(pd.read_parquet(tmp_path / "reach_holds_log.parquet")) == 39  # the last period's step was cut
    assert json.loads((tmp_path / "reach_holds_real.json").read_text())["signal"] == "SIGTERM"


class Crashes(BasePolicy):
    """A policy with a bug: raises a ``ZeroDivisionError`` at step ``at``."""

    def __init__(self, env, at: int = 30) -> None:
        super().__init__(env)
        self.at, self.count = at, 0

    def _act(self, obs):
        self.count += 1
        if self.count == self.at:
            return 1 // 0
        return np.full(6, 0.05)


def test_an_unexpected_exception_is_one_line_with_the_log_and_its_traceback_kept(
    signalling_run, tmp_path, timing_rules_off
):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    register_policy("crashes", Crashes, overwrite=True)
    outcome = CliRunner().invoke(
        app, ["real", "--connection", "sim", "--controller", "crashes", "--out", str(tmp_path)]
    )
    assert outcome.exit_code == 3, outcome.output
    assert outcome.output.strip().splitlines() == [  # when the arm started to move, then how it ended
        "real: the control loop starts: 1875 periods of 8 ms (15 s)",
        f"error: unexpected ZeroDivisionError: integer division or modulo by zero; the log so far is in {tmp_path}/ "
        "(traceback in its real.json)",
    ]
    assert signalling_run[0].stopped
    summary = json.loads((tmp_path / "reach_crashes_real.json").read_text())
    assert summary["ended"] == "error" and "1 // 0" in "".join(summary["traceback"])
    assert len(pd.read_parquet(tmp_path / "reach_crashes_log.parquet")) == 29
    assert len(pd.read_csv(tmp_path / "reach_crashes_timing.csv")) == 29


def test_the_stream_log_is_on_disk_within_a_second_while_the_run_goes(tmp_path, monkeypatch):
    import snac_gym.real.journal as journal_module
    from snac_gym.real.journal import StepJournal

    monkeypatch.setattr(journal_module, "FLUSH_EVERY", 0.05)
    path = tmp_path / "stream.csv"
    journal = StepJournal(path, 6, writer="inline")
    obs = np.arange(20.0)
    for k in range(10):
        journal.record(k, k * 0.008, 0.008, obs, 6, np.full(6, 0.1), "normal", None)
    assert path.read_text().count("\n") == 1  # buffered: only the header is out
    time.sleep(0.06)
    journal.record(10, 0.08, 0.008, obs, 6, np.full(6, 0.1), "normal", 'stale "joint" state')
    on_disk = pd.read_csv(path)  # read while the file is still open, as after a crash of the host
    assert len(on_disk) == 11 and on_disk["safety"].iloc[-1] == "stale 'joint' state"
    np.testing.assert_allclose(on_disk[[f"q_{j}" for j in range(6)]].iloc[0], obs[:6])
    journal.close()


def test_the_process_writer_writes_the_same_rows_off_the_loop_and_keeps_them_if_the_host_dies(tmp_path, monkeypatch):
    import snac_gym.real.journal as journal_module
    from snac_gym.real.journal import StepJournal

    monkeypatch.setattr(journal_module, "FLUSH_EVERY", 0.05)
    obs = np.linspace(-1.0, 1.0, 20)
    files = {}
    for writer in ("inline", "process"):
        files[writer] = tmp_path / f"{writer}.csv"
        journal = StepJournal(files[writer], 6, writer=writer)
        journal.record(0, 0.0, None, obs, 6, None, "normal", None)
        for k in range(1, 5):
            journal.record(k, k * 0.008, 0.0081, obs * k, 6, np.full(6, 0.1 * k), "normal", None)
        journal.record(5, 0.04, 0.0079, obs, 6, np.zeros(6), "protective_stop", 'controller "reports" it')
        if writer == "process":  # on disk within the flush period, while the run goes on
            deadline = time.monotonic() + 2.0
            while files[writer].read_text().count("\n") < 7 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert files[writer].read_text().count("\n") == 7
            os.kill(journal._process.pid, 0)  # still running
        journal.close()
    inline, process = (pd.read_csv(files[w]) for w in ("inline", "process"))
    pd.testing.assert_frame_equal(inline.drop(columns="monotonic_s"), process.drop(columns="monotonic_s"))
    assert process["safety"].iloc[-1] == "controller 'reports' it" and np.isnan(process["u_0"].iloc[0])
    # the host killed outright: the pipe closes, the writer drains it and exits
    path = tmp_path / "killed.csv"
    journal = StepJournal(path, 6, writer="process")
    for k in range(300):
        journal.record(k, k * 0.008, 0.008, obs, 6, np.full(6, 0.1), "normal", None)
    # What the kernel does to the host's end when it dies: the pipe's write end closed (through its file object, so
    # that nothing closes the descriptor again when the object is collected: that raised EBADF there, and could
    # close a descriptor reused since).
    journal._process.stdin.close()
    journal._process.wait(timeout=5.0)
    assert list(pd.read_csv(path)["step"]) == list(range(300))
    with pytest.raises(ValueError, match="writer must be one of \\['process', 'inline'\\], got 'thread'"):
        StepJournal(tmp_path / "x.csv", 6, writer="thread")


def test_a_completed_run_replaces_the_stream_log_with_the_full_log(tmp_path):
    from snac_gym.apps.real import run_real_episode

    run_real_episode(controller="dls", out_dir=tmp_path, connection="sim", steps=30, plots=False)
    names = {p.name for p in tmp_path.iterdir()}
    assert "reach_dls_log.parquet" in names and "reach_dls_stream.csv" not in names


def test_an_interrupted_run_keeps_the_stream_log_with_every_period(signalling_run, tmp_path):
    from snac_gym.apps.real import TerminationSignal, run_real_episode

    with pytest.raises(TerminationSignal):
        run_real_episode(controller="sends-signal", out_dir=tmp_path, connection="sim", steps=200,
                         safety=SafetyLimits(max_period=10.0, deadline_slack=10.0))  # fmt: skip
    stream = pd.read_csv(tmp_path / "reach_sends-signal_stream.csv")
    assert list(stream["step"]) == list(range(30))  # the reset's row, then one per sent command


@pytest.mark.parametrize(
    ("limits", "match"),
    [
        ({"max_joint_acceleration": np.inf}, "max_joint_acceleration must be a finite number in \\(0, 40\\]"),
        ({"max_joint_acceleration": -1.0}, "max_joint_acceleration"),
        ({"speed_scale": np.nan}, "speed_scale"),
        ({"box_low": (np.nan, -1.0, -1.0), "box_high": (1.0, 1.0, 1.0)}, "task box corners must be finite"),
        ({"box_low": (-1.0, -1.0, -1.0), "box_high": (1.0, 1.0, np.inf)}, "task box corners must be finite"),
        ({"box_low": (0.0, 0.0), "box_high": (1.0, 1.0, 1.0)}, "3 numbers each"),
        ({"box_low": (-1.0, -1.0, -1.0)}, "give both corners of the task box or neither"),
        ({"joint_limit_margin": -0.1}, "joint_limit_margin"),
        ({"joint_limit_margin": np.nan}, "joint_limit_margin"),
        ({"deadline_slack": np.nan}, "deadline_slack"),
        ({"max_period": np.inf}, "max_period"),
        ({"max_missed_deadlines": 0}, "max_missed_deadlines"),
        (
            {"max_missed_deadlines": 30, "deadline_window": 25},
            "max_missed_deadlines must be a whole number in \\[1, 25\\]",
        ),
        ({"max_stale_periods": 2.5}, "max_stale_periods"),
        ({"rest_speed": 0.0}, "rest_speed"),
    ],
)
def test_meaningless_safety_limits_are_refused(limits, match):
    with pytest.raises(ValueError, match=match):
        SafetyLimits(**limits)


@pytest.mark.parametrize("value", ["inf", "nan", "100"])
def test_the_real_command_refuses_a_meaningless_acceleration_in_one_line(tmp_path, value):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    outcome = CliRunner().invoke(
        app, ["real", "--connection", "sim", "--max-acceleration", value, "--out", str(tmp_path)]
    )
    assert outcome.exit_code == 2
    assert "max_joint_acceleration must be a finite number" in outcome.output
    assert "Traceback" not in outcome.output and not any(tmp_path.iterdir())


# ---------------------------------------------------------------------------- resuming (opt-in)


def _recovering_env(max_recoveries=1, **recovery):
    connection = FaultyConnection()
    limits = RecoveryLimits(max_recoveries=max_recoveries, **recovery)
    env = RealUREnv("reach", connection, safety=SafetyLimits(max_period=10.0, max_missed_deadlines=25), recovery=limits)
    env.reset(options={"q0": PAPER_Q0})
    return env, connection


def test_a_protective_stop_cleared_on_the_pendant_resumes_the_episode_from_rest():
    env, connection = _recovering_env()
    for _ in range(20):
        env.step(np.full(6, 0.3))
    connection.inject_fault(PROTECTIVE_STOP)
    sent = connection.inner.commands_sent
    clearing = threading.Timer(0.3, connection.inject_fault, args=(NORMAL,))  # the operator, on the pendant
    clearing.start()
    _, _, terminated, _, info = env.step(np.full(6, 0.3))
    assert not terminated and info["safety"] is None and env.stop_reason is None
    recovery = info["recovery"]
    assert recovery["kind"] == "protective stop" and recovery["cleared_by"] == "cleared on the pendant"
    assert recovery["step"] == 21 and 0.3 <= recovery["gap_s"] < 5.0
    assert connection.inner.commands_sent == sent  # nothing reached the arm while it was stopped
    _, _, _, _, info = env.step(np.full(6, 0.3))  # from rest: the first command is one acceleration step
    np.testing.assert_allclose(np.abs(info["command"]), env.safety.step_bound)
    assert env.recoveries == [recovery]


def test_recoveries_are_bounded_and_a_second_stop_ends_the_episode_as_before():
    env, connection = _recovering_env(max_recoveries=1, clear_timeout=0.2)
    env.step(np.full(6, 0.1))
    connection.inject_fault(PROTECTIVE_STOP)
    _, _, terminated, _, info = env.step(np.full(6, 0.1))
    # not cleared: the episode ends at the stop, the reason says why it did not resume
    assert terminated and info["safety"] == "controller reports protective_stop; not cleared within 0.2 s"
    _assert_stopped_at_rest(env, connection)
    env, connection = _recovering_env(max_recoveries=1)
    env.step(np.full(6, 0.1))
    connection.inject_fault(PROTECTIVE_STOP)
    threading.Timer(0.1, connection.inject_fault, args=(NORMAL,)).start()
    assert env.step(np.full(6, 0.1))[4]["safety"] is None
    connection.inject_fault(PROTECTIVE_STOP)  # the second: none left
    _, _, terminated, _, info = env.step(np.full(6, 0.1))
    assert terminated and info["safety"] == "controller reports protective_stop" and len(env.recoveries) == 1


def test_an_emergency_stop_is_never_resumed():
    env, connection = _recovering_env(max_recoveries=3)
    env.step(np.full(6, 0.1))
    connection.inject_fault(EMERGENCY_STOP)
    _, _, terminated, _, info = env.step(np.full(6, 0.1))
    assert terminated and info["safety"] == "controller reports emergency_stop" and env.recoveries == []


def test_an_arm_that_moved_during_the_stop_is_not_resumed():
    env, connection = _recovering_env()
    env.step(np.full(6, 0.1))
    connection.inject_fault(PROTECTIVE_STOP)

    def pushed_into_the_margin():  # someone moved the arm by hand, next to a joint limit
        q = connection.inner.read_state()[0]
        q[5] = env.kinematics.upper_limits[5] - 0.05
        connection.inner.arm.set_joint_positions(q)
        connection.inject_fault(NORMAL)

    threading.Timer(0.1, pushed_into_the_margin).start()
    _, _, terminated, _, info = env.step(np.full(6, 0.1))
    assert terminated and env.recoveries == []
    assert info["safety"].startswith(
        "controller reports protective_stop; not resumed after the protective stop: joint 5"
    )


def test_a_lost_link_with_no_recoveries_left_or_no_reconnect_propagates_as_before():
    env, connection = _recovering_env()

    def lost(_):
        raise ConnectionFailure("connection to the arm at 10.0.0.1 was lost")

    connection.command = lost  # a simulated arm cannot reconnect: the failure ends the run as without recovery
    with pytest.raises(ConnectionFailure, match="was lost"):
        env.step(np.full(6, 0.1))
    assert env.stop_reason.startswith("ConnectionFailure during step") and env.recoveries == []


@pytest.mark.parametrize(
    ("limits", "match"),
    [
        ({"max_recoveries": -1}, "max_recoveries must be a whole number in \\[0, 100\\]"),
        ({"max_recoveries": 1, "clear_timeout": float("nan")}, "clear_timeout must be a finite number"),
        ({"max_recoveries": 1, "reconnect_timeout": 0.0}, "reconnect_timeout must be a finite number in \\(0"),
        ({"unlock_protective_stop": True}, "needs max_recoveries of at least 1"),
    ],
)
def test_meaningless_recovery_limits_are_refused(limits, match):
    with pytest.raises(ValueError, match=match):
        RecoveryLimits(**limits)


def test_the_real_command_refuses_an_unlock_without_recoveries(tmp_path):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    outcome = CliRunner().invoke(
        app, ["real", "--connection", "sim", "--unlock-protective-stop", "--out", str(tmp_path)]
    )
    assert outcome.exit_code == 2 and "needs max_recoveries of at least 1 (--max-recoveries N)" in outcome.output


def test_a_protective_stop_unlocked_after_the_lockout_resumes_and_a_dry_run_never_unlocks(tmp_path, monkeypatch):
    import snac_gym.real.env as env_module
    from snac_gym.apps.real import run_real_episode

    monkeypatch.setattr(env_module, "PROTECTIVE_STOP_LOCKOUT", 0.2)  # UR's 5 s, shortened
    env, connection = _recovering_env(unlock_protective_stop=True)
    env.step(np.full(6, 0.1))
    connection.inject_fault(PROTECTIVE_STOP)
    started = time.monotonic()
    _, _, terminated, _, info = env.step(np.full(6, 0.1))
    assert not terminated and info["recovery"]["cleared_by"] == "unlocked from the dashboard"
    assert time.monotonic() - started >= 0.2 and connection.safety_state() == NORMAL
    with pytest.raises(ValueError, match="not in a dry run"):
        run_real_episode(out_dir=tmp_path, connection="sim", dry_run=True,
                         recovery=RecoveryLimits(max_recoveries=1, unlock_protective_stop=True))  # fmt: skip
