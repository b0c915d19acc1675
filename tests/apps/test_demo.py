"""The paper's demonstrations, the rollout log and the act benchmark."""

import hashlib
import json
import os

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from snac_gym.apps.bench import format_act_bench, run_act_bench
from snac_gym.apps.cli import app
from snac_gym.apps.demo import COMPILING, demo_options, run_demo
from snac_gym.apps.studies import discretisation_study, random_episode_study, summarise_random_study, summarise_study
from snac_gym.common.errors import MissingExtraError
from snac_gym.metrics import demo_metrics
from snac_gym.policies import register_policy, registry
from snac_gym.policies.base import BasePolicy
from snac_gym.policies.snac import SNACPolicy
from snac_gym.references import PAPER_Q0, PAPER_TARGET
from snac_gym.rollout import log_array, log_columns, read_log, rollout, write_log
from snac_gym.tasks import TASKS

PANELS = ("path", "error", "joint_velocities", "cost", "figure3", "critic_weights", "optimality")
DIAGNOSTICS = {"reach": ["hjb_residual", "hjb_ratio", "critic_error"], "track": ["hjb_residual", "hjb_ratio"]}


def _expected_columns(n_joints, task_dim, n_weights):
    cols = ["t"] + [f"q_{i}" for i in range(n_joints)] + [f"u_{i}" for i in range(n_joints)]
    for prefix in ("x", "x_d", "xdot_d", "e"):
        cols += [f"{prefix}_{i}" for i in range(task_dim)]
    return cols + [f"w_{i}" for i in range(n_weights)]


def test_reach_demo_meets_the_acceptance_at_its_default_horizon(tmp_path):
    result = run_demo("reach", "snac", tmp_path, seed=0)
    m, log = result.metrics, result.log
    assert m.steps == len(log) == 1500  # the reach task's 12 s horizon
    assert m.final_error <= 1e-3
    # The paper's SNAC (random Ŵ₀ from seed 0): 1 mm first reached at 10.02 s, V = 43.6 measured.
    assert m.time_to_1mm is not None and m.time_to_1mm < 11.0
    assert m.settling_time is not None and m.settling_time < 11.0
    assert m.max_speed_ratio < 1.0 and m.clipped_steps == 0  # the per-second law never reaches a limit here
    assert m.cost_total < 60.0
    assert m.critic_error_final > 1.0  # the paper's law does not learn P* (2.52 measured)
    assert m.cost_total == pytest.approx(m.cost_error + m.cost_effort + m.cost_smoothness)
    assert np.all(np.abs(log_array(log, "u")) <= np.asarray(log.attrs["velocity_limits"]))
    assert list(log.columns) == _expected_columns(6, 3, 6) + DIAGNOSTICS["reach"]
    np.testing.assert_allclose(log_array(log, "x_d")[0], PAPER_TARGET)
    np.testing.assert_allclose(log_array(log, "q")[0], PAPER_Q0, atol=1e-12)
    for panel in PANELS:
        png = tmp_path / f"reach_snac_{panel}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    stored = read_log(tmp_path / "reach_snac_log.parquet")
    pd.testing.assert_frame_equal(stored, log, check_exact=True)
    assert stored.attrs["final_e"] == log.attrs["final_e"]
    assert (tmp_path / "reach_snac_summary.json").exists()


def test_track_demo_settles_under_5_mm_and_stays(tmp_path):
    result = run_demo("track", "snac", tmp_path, seed=0, plots=False)
    m, log = result.metrics, result.log
    assert m.steps == len(log) == 2500  # the env's 20 s episode
    # The paper's SNAC (random Ŵ₀ from seed 0, ξ = [e; x_d]): under 5 mm from 12.28 s, V = 52.0 measured.
    assert m.settling_time is not None and m.settling_time <= 14.0
    assert m.max_error_after_settling < 5e-3
    norms = np.linalg.norm(log_array(log, "e"), axis=1)
    assert norms[log["t"].to_numpy() >= 14.0].max() < 5e-3
    assert m.max_speed_ratio <= 1.0
    assert m.cost_total < 80.0
    assert list(log.columns) == _expected_columns(6, 3, 21) + DIAGNOSTICS["track"]
    # x_d moves on the paper's circle: radius 0.2 m about the centre, in the z = 0.5 m plane.
    x_d = log_array(log, "x_d")
    np.testing.assert_allclose(np.linalg.norm(x_d - [-0.7, 0.0, 0.5], axis=1), 0.2, atol=1e-12)
    assert not list(tmp_path.glob("*.png"))


@pytest.mark.parametrize("task", ["reach", "track"])
def test_same_seed_reproduces_the_log_bit_for_bit(tmp_path, task):
    random = {"initial_weights": "uniform"}  # the seed draws Ŵ₀
    logs = [
        run_demo(task, "snac", tmp_path / str(i), seed=5, steps=250, plots=False, policy_kwargs=random).log
        for i in range(2)
    ]
    assert logs[0].to_numpy().tobytes() == logs[1].to_numpy().tobytes()
    assert logs[0].attrs == logs[1].attrs
    files = [tmp_path / str(i) / f"{task}_snac_log.parquet" for i in range(2)]
    digests = [hashlib.sha256(path.read_bytes()).hexdigest() for path in files]
    assert digests[0] == digests[1]
    other = run_demo(task, "snac", None, seed=6, steps=250, policy_kwargs=random).log
    assert not np.array_equal(log_array(other, "w")[0], log_array(logs[0], "w")[0])
    # Ŵ₀ = c on the squared terms does not depend on the seed: the demo is then seed-free.
    identity = {"initial_weights": "identity"}
    fixed = [run_demo(task, "snac", None, seed=seed, steps=50, policy_kwargs=identity).log for seed in (5, 6)]
    assert fixed[0].to_numpy().tobytes() == fixed[1].to_numpy().tobytes()


def test_rollout_rows_hold_the_state_at_the_start_of_each_step():
    env = gym.make("snac_gym/UR10Reach-v0")
    policy = SNACPolicy(env)
    log = rollout(env, policy, options=demo_options("reach"), seed=1, steps=40)
    assert len(log) == 40 and log.attrs["task"] == "reach" and log.attrs["truncated"] is False
    dt = env.unwrapped.dt
    np.testing.assert_allclose(log["t"].to_numpy(), np.arange(40) * dt)
    q, u = log_array(log, "q"), log_array(log, "u")
    e, x, x_d = log_array(log, "e"), log_array(log, "x"), log_array(log, "x_d")
    np.testing.assert_allclose(e, x - x_d, atol=1e-15)
    kin = env.unwrapped.kinematics
    np.testing.assert_allclose(x[7], kin.forward(q[7]), atol=1e-12)
    # Replaying the logged commands from the same reset gives row k+1 after applying u_k (bit for bit).
    obs, _ = env.reset(seed=1, options=demo_options("reach"))
    for k in range(40):
        np.testing.assert_array_equal(obs[:6], q[k])
        obs, *_ = env.step(u[k])
    np.testing.assert_array_equal(obs[:6], log.attrs["final_q"])
    # w row k: the weights before step k's update (row 0 = Ŵ₀ of the reset seed).
    fresh = SNACPolicy(env)
    fresh.reset(seed=1)
    np.testing.assert_array_equal(log_array(log, "w")[0], fresh.critic_weights)
    env.close()


class _HoldStill(BasePolicy):
    """A policy with no internals: commands zero."""

    def _act(self, obs):
        return np.zeros(self.kinematics.n_joints)


@pytest.fixture
def isolated_registry(monkeypatch):
    """Registrations made in a test vanish after it."""
    monkeypatch.setattr(registry, "_BUILTIN", dict(registry._BUILTIN))
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))


_ZEROS: list = []  # the policy's compiled function, made on its first act: compiled once in this process


def _zeros(count):
    return np.zeros(count)


class _HoldStillCompiled(_HoldStill):
    """:class:`_HoldStill` through a function numba compiles at its first act in this process (no cache)."""

    def _act(self, obs):
        if not _ZEROS:
            from numba import njit

            _ZEROS.append(njit(_zeros))
        return _ZEROS[0](self.kinematics.n_joints)


def test_any_registered_policy_runs_the_demo(tmp_path, isolated_registry):
    register_policy("hold-still-demo-test", _HoldStillCompiled, overwrite=True)
    _ZEROS.clear()
    said: list[str] = []
    result = run_demo("track", "hold-still-demo-test", tmp_path, steps=30, csv=True, progress=said.append)
    # What a first demo after an install says on stderr: that kernels compile (once, as the first one starts), the
    # steps run, then the figures; each line whole.
    assert said[0] == COMPILING and said[1].startswith("demo: 30/30 steps (100 %), "), said
    assert said[2:] == [f"demo: drawing 5 figures into {tmp_path}/"], said
    again: list[str] = []
    run_demo("track", "hold-still-demo-test", tmp_path / "again", steps=30, plots=False, progress=again.append)
    assert len(again) == 1 and again[0].startswith("demo: 30/30 steps"), again  # compiled already: nothing said
    log = result.log
    assert list(log.columns) == _expected_columns(6, 3, 0)  # no critic, no w columns
    assert not (tmp_path / "track_hold-still-demo-test_critic_weights.png").exists()
    assert (tmp_path / "track_hold-still-demo-test_figure3.png").exists()
    csv = pd.read_csv(tmp_path / "track_hold-still-demo-test_log.csv")
    np.testing.assert_array_equal(csv.to_numpy(), log.to_numpy())  # %.17g round-trips float64
    assert result.metrics.final_error == pytest.approx(np.linalg.norm(log.attrs["final_e"]))


@pytest.mark.parametrize("engine", ["kinematic", "pybullet"])
def test_the_demo_runs_on_the_engine_asked_for_and_says_which(tmp_path, engine):
    """``--engine kinematic`` is the paper's exact model: each logged θ is the one before plus uΔt, to rounding (an
    independent integration of the logged commands). PyBullet's motors track u only closely, so there the identity
    fails by far more than rounding: the option is not ignored. The summary and the printed header say which."""
    result = run_demo("reach", "lqr", out_dir=tmp_path, steps=60, plots=False, engine=engine)
    log = result.log
    q, u = log[[f"q_{j}" for j in range(6)]].to_numpy(), log[[f"u_{j}" for j in range(6)]].to_numpy()
    integrated = q[:-1] + u[:-1] * log.attrs["dt"]
    gap = float(np.abs(q[1:] - integrated).max())
    assert (gap < 1e-12) if engine == "kinematic" else (gap > 1e-6), gap
    assert json.loads((tmp_path / "reach_lqr_summary.json").read_text())["engine"] == engine
    assert result.summary().splitlines()[0].endswith(f"60 steps, {engine} engine")


def test_the_demo_solves_pybullets_motors_as_asked_and_says_so_only_where_it_is_not_v0s_solve(tmp_path):
    """``--pybullet-solver dantzig`` (the -v1 ids' solve): the lqr reach demo's θ follows θ + uΔt to rounding where
    the motors are within their force bounds (after the first steps from rest), which PyBullet's default solve misses
    by its lag under gravity; the summary and the header name it, and a default run's outputs carry no new key."""
    gaps = {}
    for solver in ("pgs", "dantzig"):
        out = tmp_path / solver
        result = run_demo("reach", "lqr", out_dir=out, steps=300, plots=False, pybullet_solver=solver)
        log = result.log
        q, u = log[[f"q_{j}" for j in range(6)]].to_numpy(), log[[f"u_{j}" for j in range(6)]].to_numpy()
        gaps[solver] = float(np.abs(q[101:] - (q[100:-1] + u[100:-1] * log.attrs["dt"])).max())
        summary = json.loads((out / "reach_lqr_summary.json").read_text())
        header = result.summary().splitlines()[0]
        if solver == "pgs":
            assert "pybullet_solver" not in summary and header.endswith("300 steps, pybullet engine")
        else:
            assert summary["pybullet_solver"] == "dantzig"
            assert header.endswith("300 steps, pybullet engine (pybullet_solver=dantzig)")
    assert gaps["dantzig"] < 1e-12 < 1e-7 < gaps["pgs"], gaps


def test_log_columns_follow_the_robot():
    assert log_columns(7, 2, 3) == _expected_columns(7, 2, 3)
    assert len(log_columns(6, 3)) == 1 + 2 * 6 + 4 * 3


def test_metrics_on_a_hand_made_log():
    dt = 0.5
    errors = np.array([[3e-3, 0, 0], [2e-3, 0, 0], [4e-3, 0, 0], [0.5e-3, 0, 0]])
    log = pd.DataFrame(
        {
            "t": np.arange(4) * dt,
            **{f"e_{i}": errors[:, i] for i in range(3)},
            **{f"u_{j}": [2.0, 0.0, 0.0, 0.0] if j == 0 else [0.0] * 4 for j in range(2)},
        }
    )
    log.attrs = {"dt": dt, "final_e": [0.2e-3, 0, 0], "final_t": 2.0, "velocity_limits": [2.0, 1.0]}
    m = demo_metrics(log, tolerance=1e-3)
    assert m.final_error == pytest.approx(0.2e-3)
    assert m.time_to_1mm == pytest.approx(1.5)
    assert m.settling_time == pytest.approx(1.5) and m.max_error_after_settling == pytest.approx(0.5e-3)
    assert m.descent_fraction == pytest.approx(3 / 4)  # only step 1 → 2 grows ‖e‖
    assert m.clipped_steps == 1 and m.max_speed_ratio == pytest.approx(1.0)


def test_the_demo_success_rule_is_the_evaluators_joint_limits_included():
    """The reach rule by hand (final ‖e‖ ≤ 1 mm), and a run that ends on target after crossing a joint limit
    (θ_K past θ⁺, as the evaluator's success column counts it) does not succeed."""
    dt = 0.5
    log = pd.DataFrame(
        {
            "t": np.arange(2) * dt,
            **{f"e_{i}": [3e-3, 1e-3] if i == 0 else [0.0, 0.0] for i in range(3)},
            **{f"u_{j}": [0.0, 0.0] for j in range(2)},
            **{f"q_{j}": [0.0, 0.5] for j in range(2)},
        }
    )
    log.attrs = {
        "dt": dt,
        "final_e": [0.2e-3, 0, 0],
        "final_t": 1.0,
        "velocity_limits": [2.0, 1.0],
        "final_q": [0.9, 0.5],
    }
    assert demo_metrics(log, 1e-3).success("reach")  # limits not given: the error rule alone
    inside = demo_metrics(log, 1e-3, (np.full(2, -1.0), np.full(2, 1.0)))
    assert inside.joint_limit_margin == pytest.approx(0.1) and inside.success("reach")
    crossed = demo_metrics(log, 1e-3, (np.full(2, -1.0), np.full(2, 0.8)))
    assert crossed.joint_limit_margin == pytest.approx(-0.1) and not crossed.success("reach")
    track = demo_metrics(log, 1e-3)  # the second half is step 1 alone: 1 mm, within the track rule's 5 mm
    assert track.mean_error_2nd_half == pytest.approx(1e-3) and track.success("track")


def test_write_log_round_trips(tmp_path):
    env = gym.make("snac_gym/UR10EllipseTrack-v0")
    log = rollout(env, SNACPolicy(env), options=demo_options("track"), seed=2, steps=20)
    env.close()
    written = write_log(log, tmp_path / "run", csv=True)
    assert [p.suffix for p in written] == [".parquet", ".csv", ".json"]
    back = read_log(written[0])
    pd.testing.assert_frame_equal(back, log, check_exact=True)
    assert back.attrs["reference"] == log.attrs["reference"]


def test_cli_demo_prints_the_figures(tmp_path):
    args = ["demo", "--task", "reach", "--steps", "200", "--out", str(tmp_path), "--seed", "0", "--no-plots"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    for phrase in ("final error", "time to first reach 1 mm", "eᵀė ≤ 0"):
        assert phrase in result.stdout
    assert result.stderr.startswith("demo: 200/200 steps (100 %), ")  # the progress on stderr, the figures on stdout
    assert "steps (" not in result.stdout
    assert (tmp_path / "reach_snac_log.parquet").exists()
    bad = CliRunner().invoke(app, ["demo", "--task", "orbit", "--out", str(tmp_path)])
    assert bad.exit_code != 0
    unknown = CliRunner().invoke(app, ["demo", "--controller", "no-such-policy", "--out", str(tmp_path)])
    assert unknown.exit_code == 2 and "unknown policy" in unknown.output


def test_act_bench_reports_every_task_and_skips_what_does_not_build(isolated_registry):
    register_policy("broken-bench-test", "no_such_module_for_bench:Policy", overwrite=True)
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    results = run_act_bench(names=("snac", "broken-bench-test"), calls=100)
    if cores is not None:  # the bench runs on one core and gives the caller its cores back
        assert os.sched_getaffinity(0) == cores
    for task in ("reach", "track"):
        row = results["snac"][task]
        assert 0 < row["median_us"] <= row["p99_us"] and row["calls"] == 100
    assert "error" in results["broken-bench-test"]
    text = format_act_bench(results)
    assert "snac" in text and "skipped" in text
    cpu = run_act_bench(names=("snac",), tasks=("track",), calls=100, clock="cpu")
    assert cpu["snac"]["track"]["median_us"] > 0
    with pytest.raises(ValueError, match="clock"):
        run_act_bench(calls=100, clock="sundial")


def test_studies_report_every_option_and_the_success_criteria():
    assert {name: task.horizon_s for name, task in TASKS.items()} == {"reach": 12.0, "track": 20.0}
    runs = discretisation_study(
        tasks=("reach",),
        seeds=(0, 1),
        weight_updates=("euler",),
        learning_rate_units=("per_second",),
        freeze_options=(False,),
        schedule_clocks=("seconds",),
        steps={"reach": 30},
        initial_weights=(("identity", 2.0), ("uniform", 3.0)),
    )
    assert list(runs.initial_weights) == ["identity", "uniform", "uniform"]  # identity Ŵ₀ ignores the seed
    assert list(runs.initial_weight_scale) == [2.0, 3.0, 3.0] and set(runs.steps) == {30}
    table = summarise_study(runs)
    assert list(table.seeds) == [1, 2] and "max_speed_ratio" in table.columns
    random = random_episode_study(
        {"default": {}}, tasks=("reach", "track"), episodes=2, horizons={"reach": (0.1, 0.2), "track": (0.2,)}
    )
    assert len(random) == 2 * 2 + 2
    reach = random[random.task == "reach"]
    assert (reach.success == (reach.final_error <= 1e-3)).all()
    track = random[random.task == "track"]
    assert (track.success == (track.mean_error_second_half <= 5e-3)).all()
    np.testing.assert_allclose(random.cost_total, random.cost_error + random.cost_effort + random.cost_smoothness)
    summary = summarise_random_study(random)
    assert list(summary.horizon_s) == [0.1, 0.2, 0.2]


def _colour_pixels(fig, ax, colour, tolerance=40):
    """Pixels of ``colour`` (within ``tolerance`` per channel) inside ``ax`` after drawing ``fig``."""
    from matplotlib.colors import to_rgb

    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    box = ax.get_window_extent()
    height = image.shape[0]
    region = image[int(height - box.y1) : int(height - box.y0), int(box.x0) : int(box.x1)]
    target = np.array(to_rgb(colour)) * 255
    return int(np.all(np.abs(region - target) <= tolerance, axis=-1).sum())


def test_cost_panel_shows_a_dominant_term_under_the_total():
    """The running smoothness term, nearly all of V (a jump from rest), stays visible under the total."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from snac_gym.apps.plots import plot_cost

    dt, steps = 0.008, 500
    t = np.arange(steps) * dt
    columns = {"t": t}
    for i in range(3):
        columns[f"e_{i}"] = 1e-3 * np.exp(-t)
    for i in range(6):
        columns[f"u_{i}"] = np.where(t < 0.5, 0.5, 0.0) if i == 0 else np.zeros(steps)
    log = pd.DataFrame(columns)
    log.attrs["dt"] = dt
    fig = plot_cost(log)
    try:
        top, bottom = fig.axes[:2]
        lines = {line.get_label().split(" ")[0]: line for line in bottom.get_lines()}
        smooth, total = lines["smoothness"].get_ydata(), lines["total"].get_ydata()
        assert smooth[-1] / total[-1] > 0.99  # the case in point: the term is nearly all of the total
        assert lines["total"].get_zorder() > lines["smoothness"].get_zorder()
        assert lines["total"].get_linestyle() != "-"
        assert lines["total"].get_linewidth() < lines["smoothness"].get_linewidth()
        # Both are seen in the drawn image: the smoothness colour and the total's black.
        assert _colour_pixels(fig, bottom, "C2") > 200
        assert _colour_pixels(fig, bottom, "k", tolerance=60) > 200
    finally:
        plt.close(fig)


def test_the_figure3_panels_name_what_they_draw(tmp_path):
    """The track demo's panels: the whole ellipse beside the part x_d covers, a legend below the 3-D axes, at
    most 5 tick labels per 3-D axis, the error components named x, y, z, and a legend entry for the limits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from snac_gym.apps.plots import plot_figure3

    log = run_demo("track", "snac", tmp_path, seed=0, steps=400, plots=False).log
    fig = plot_figure3(log, tolerance=5e-3)
    try:
        fig.canvas.draw()
        path, error = fig.axes[0], fig.axes[1]
        labels = [text.get_text() for text in path.get_legend().get_texts()]
        assert "reference ellipse (whole)" in labels and any(label.startswith("desired $x_d(t)$") for label in labels)
        whole = next(line for line in path.get_lines() if line.get_label() == "reference ellipse (whole)")
        assert len(whole.get_data_3d()[0]) > 100  # the closed curve, not the arc x_d covered (400 steps: 3.2 s)
        legend_box = path.get_legend().get_window_extent()
        assert legend_box.y1 <= path.get_window_extent().y0 + 1  # below the axes, off the path
        for axis in (path.xaxis, path.yaxis, path.zaxis):
            low, high = sorted(axis.get_view_interval())
            assert len([tick for tick in axis.get_majorticklocs() if low <= tick <= high]) <= 5
        assert [t.get_text() for t in error.get_legend().get_texts()] == ["$e_{x}$", "$e_{y}$", "$e_{z}$"]
        velocities = fig.axes[3]
        assert "±limit (the joint's colour)" in [t.get_text() for t in velocities.get_legend().get_texts()]
    finally:
        plt.close(fig)


def test_a_demo_that_fails_before_writing_leaves_no_folder_and_keeps_one_that_was_there(tmp_path, monkeypatch):
    """The folder is made before the rollout (so that an unusable --out is refused first) and removed again if the demo
    ends before writing there: a controller's knob it does not take, an engine whose extra is missing."""
    with pytest.raises(TypeError, match="no_such_knob"):
        run_demo(controller="dls", out_dir=tmp_path / "new" / "run", steps=5, policy_kwargs={"no_such_knob": 1})

    def missing_extra(*args, **kwargs):
        raise MissingExtraError("physics='mujoco' needs the 'mujoco' extra")

    monkeypatch.setattr("snac_gym.apps.demo.make_task_env", missing_extra)
    (tmp_path / "there").mkdir()
    with pytest.raises(MissingExtraError):
        run_demo(out_dir=tmp_path / "there", engine="mujoco")
    assert [p.name for p in tmp_path.iterdir()] == ["there"]
