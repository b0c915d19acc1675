"""`snac-gym real --robot` against the emulated controller of each UR model: the start pose and the target
given on the command line, the arm within 1 mm of the target at the end, exit code 0."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("rtde_control", reason="needs the real extra (ur-rtde)")

from _loopback import emulator_host  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from snac_gym.apps.cli import app  # noqa: E402
from snac_gym.evaluation.samples import generate_samples  # noqa: E402
from snac_gym.kinematics import Kinematics  # noqa: E402
from snac_gym.real.emulator.process import EmulatorProcess  # noqa: E402
from snac_gym.references import PAPER_Q0 as PAPER_POSE  # noqa: E402
from snac_gym.sampling import SampleSpace  # noqa: E402

pytestmark = pytest.mark.realtime
HOST = emulator_host()
#: The paper's start pose: elbow up, wrist down on every UR model.
PAPER_Q0 = np.asarray(PAPER_POSE, dtype=float)


@pytest.fixture(scope="module", params=["ur3", "ur5", "ur10"])
def model(request) -> Iterator[tuple[str, EmulatorProcess]]:
    with EmulatorProcess(series="cb", host=HOST, bind_timeout=90.0, robot=request.param) as emulator:
        yield request.param, emulator


def _numbers(values: np.ndarray) -> str:
    return ",".join(f"{v:.6f}" for v in values)


@pytest.mark.realtime(seconds=10)
def test_real_reaches_a_command_line_target_on_each_ur_model(model, tmp_path):
    robot, emulator = model
    emulator.reset()
    kinematics = Kinematics(robot)
    # A start pose and a target the arm's own samplers draw (seed 7: not the paper's numbers, which only the
    # UR10 reaches), as a user picks them in the arm's sample cuboid.
    (sample,) = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 7, "reach", range(1))
    out = tmp_path / robot
    result = CliRunner().invoke(app, [
        "real", "--connection", "rtde", "--host", HOST, "--robot", robot, "--controller", "lqr", "--steps", "1000",
        "--q0", _numbers(sample.q0), "--target", _numbers(sample.reference.target), "--no-plots", "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    log = pd.read_parquet(out / "reach_lqr_log.parquet")
    assert float(np.linalg.norm(log[["e_0", "e_1", "e_2"]].to_numpy()[-1])) < 1e-3
    np.testing.assert_allclose(log[[f"q_{j}" for j in range(6)]].to_numpy()[0], sample.q0, atol=1e-3)
    status = emulator.status()
    assert status["protocol_errors"] == [] and max(map(abs, status["qd"])) == 0.0
    setup = pd.read_json(out / "reach_lqr_real.json", typ="series")["setup"]
    assert setup["robot"] == robot and np.allclose(setup["target"], sample.reference.target)


@pytest.mark.realtime(seconds=4)
def test_a_protective_stop_mid_run_exits_5_and_no_speedj_follows(model, tmp_path):
    """The controller reports a protective stop 1.5 s into the run: the command exits 5 (a script sees it), and
    no speed command reaches the controller after the host has had one period to read the stop."""
    robot, emulator = model
    emulator.reset()
    stopped_at: list[float] = []

    def stop_later() -> None:
        time.sleep(1.5)
        stopped_at.append(time.monotonic())
        emulator.protective_stop()

    threading.Thread(target=stop_later, daemon=True).start()
    result = CliRunner().invoke(app, [
        "real", "--connection", "rtde", "--host", HOST, "--robot", robot, "--controller", "lqr", "--steps", "1000",
        "--q0", _numbers(PAPER_Q0), "--target", _numbers(Kinematics(robot).forward(PAPER_Q0) + 0.02),
        "--no-plots", "--out", str(tmp_path / robot),
    ])  # fmt: skip
    assert result.exit_code == 5, result.output
    assert "controller reports protective_stop" in result.output
    assert emulator.speed_commands_after(stopped_at[0] + 0.1) == []
    emulator.reset()
