"""``snac-gym bench``: what it prints is its table alone."""

from __future__ import annotations

import os

import pytest

from snac_gym.apps.bench import format_env_bench, run_env_bench


def test_panda_gyms_env_prints_nothing_of_its_own_on_stdout(capfd):
    """PyBullet writes the options panda-gym connects with ("argv[0]=--background_color_red=...") to the process's
    stdout, before the table: ``snac-gym bench > table.txt`` got three lines of them."""
    pytest.importorskip("panda_gym")
    results = run_env_bench(steps=100, physics=())
    out, _ = capfd.readouterr()
    assert out == "", out
    assert list(results) == ["PandaReachJoints-v3 (panda-gym)"] and results["PandaReachJoints-v3 (panda-gym)"]
    assert format_env_bench(results).splitlines()[0].split() == [
        "env",
        "steps/s",
        "control",
        "dt",
        "real-time",
        "factor",
    ]


def test_quiet_output_silences_the_descriptors_c_code_writes_to_under_a_capture(capfd):
    """C code writes to descriptors 1 and 2 whatever ``sys.stdout`` is: under pytest's capture it has no usable
    ``fileno()``, and the old ``quiet_output`` silenced nothing there."""
    from snac_gym.common._quiet import quiet_output

    print("before", flush=True)
    with quiet_output():
        os.write(1, b"from C, on stdout\n")
        os.write(2, b"from C, on stderr\n")
    print("after", flush=True)
    assert capfd.readouterr() == ("before\nafter\n", "")


def test_the_envs_are_timed_in_interleaved_rounds_and_each_row_keeps_its_best(monkeypatch):
    """Each round times every env once, so a host whose speed drifts during the run slows every env alike: timed one
    env after another, the envs of a slow minute read slow and their ratio to panda-gym with them."""
    from snac_gym.apps import bench

    order: list[int] = []
    clock = iter([0.5, 0.4, 0.6, 0.45, 0.3, 0.35])  # seconds of each timed run, in the order they are made

    def timed(env, actions, steps):
        order.append(id(env))
        return next(clock)

    monkeypatch.setattr(bench, "_timed_run", timed)
    results = run_env_bench(steps=100, include_panda=False, physics=("pybullet",), rounds=3)
    assert list(results) == ["snac_gym/UR10Reach-v0 (pybullet)", "snac_gym/UR10EllipseTrack-v0 (pybullet)"]
    assert len(set(order)) == 2 and order[:2] == order[2:4] == order[4:]  # A B A B A B
    reach, track = results.values()
    assert reach["round_seconds"] == (0.5, 0.6, 0.3) and track["round_seconds"] == (0.4, 0.45, 0.35)
    assert reach["steps_per_s"] == 100 / 0.3 and track["real_time_factor"] == 100 * track["control_dt"] / 0.35


def test_the_ratio_to_panda_gym_is_printed_round_by_round_beside_the_best_runs():
    """Paired by round: each round's real-time factor over panda-gym's in the same round (an independent computation
    of the three rounds below), with the ratio of the best runs first."""
    from snac_gym.apps.bench import PANDA_GYM

    ours = {"steps_per_s": 1000 / 0.5, "real_time_factor": 16.0, "control_dt": 0.008, "round_seconds": (0.5, 0.8, 0.6)}
    panda = {"steps_per_s": 1000 / 2.0, "real_time_factor": 20.0, "control_dt": 0.04, "round_seconds": (2.0, 2.4, 3.6)}
    text = format_env_bench({"ours (pybullet)": ours, PANDA_GYM: panda})
    # best runs: (8/0.5)/(40/2.0) = 0.8; rounds: (8/0.5)/(40/2.0) = 0.8, (8/0.8)/(40/2.4) = 0.6, (8/0.6)/(40/3.6) = 1.2
    assert text.splitlines()[-1] == (
        "ours (pybullet): 0.80x panda-gym's real-time factor (best runs; round by round 0.60-1.20x, median 0.80x)"
    )


def test_a_comparison_left_out_for_a_missing_extra_is_said_with_the_extra(monkeypatch):
    """Without panda-gym or MuJoCo the bench's table is shorter: a line names each comparison left out and its extra,
    and none is printed for what was measured."""
    from snac_gym.apps import bench

    monkeypatch.setattr(bench, "_timed_run", lambda env, actions, steps: 0.5)
    monkeypatch.setattr(bench, "_panda_gym_registered", lambda: False)
    results = run_env_bench(steps=100, include_panda=True, physics=("pybullet",), rounds=1)
    assert bench.left_out(results, include_panda=True, physics=("pybullet",)) == [
        "left out: panda-gym's PandaReachJoints-v3, and so the ratio to it (panda-gym does not import: "
        "the 'bench' extra, pip install -e \".[bench]\")"
    ]
    assert bench.left_out(results, include_panda=False, physics=("pybullet",)) == []  # --no-panda: not asked for
    assert bench.left_out(results, include_panda=False, physics=("pybullet", "mujoco")) == [
        "left out: physics='mujoco' (the 'mujoco' extra is not installed: pip install -e \".[mujoco]\")"
    ]
    with_mujoco = {**results, "snac_gym/UR10Reach-v0 (mujoco)": results["snac_gym/UR10Reach-v0 (pybullet)"]}
    assert bench.left_out(with_mujoco, include_panda=False, physics=("pybullet", "mujoco")) == []
