"""The trade-off sweep (``snac-gym evaluate --sweep``): each controller over its effort knob.

One matched point of one cost is not a comparison: a controller may be cheaper at equal
effort only because it is less accurate, or only at that effort. The sweep runs every
controller (not ``optimal``) at a geometric grid of its effort knob,

    knob = default × span ** linspace(−1, 1, points)

(``default``: the knob's value with the run's arguments, the controller's own setting), plus
the knob value of the main run (with effort matching: the *equal-effort point*), and reports
V/N beside accuracy and peak effort at every point:

* ``OUT/sweep.csv``: one row per task, controller and knob value (columns in
  :data:`SWEEP_COLUMNS`), rewritten as each point completes;
* ``OUT/tradeoff.png``: per task, V/N against the success rate, the median error and the peak
  effort, one line per controller in knob order, the main run's point starred, the points whose
  success rate is below ``success_threshold`` hollow.

The main run (:func:`~snac_gym.evaluation.runner.run_evaluation`) comes first and the sweep's full
passes go into its run folder through the runner's own machinery (the executor, the store,
``run_passes``): a pass at a knob value the main run already evaluated is read back from its
part files, every finished job is stored at once, and ``--resume`` continues an interrupted
sweep without recomputing its finished jobs.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.controllers import ControllerSpec, resolve_controllers
from snac_gym.evaluation.execution.executors import open_executor
from snac_gym.evaluation.execution.passes import EvaluationRun
from snac_gym.evaluation.execution.progress import Progress
from snac_gym.evaluation.reports.summary import controller_label
from snac_gym.evaluation.run_config import EvaluationConfig
from snac_gym.evaluation.runner import load_samples, run_evaluation
from snac_gym.evaluation.store import RunStore

from snac_gym.common.outputs import write_whole
from snac_gym.kernels.compiled import evaluator_kernel_modules
from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

#: Knob values per controller and task (besides the main run's), and the grid's reach either
#: side of the default: 7 points over default/4 … default·4.
DEFAULT_POINTS, DEFAULT_SPAN = 7, 4.0
#: Most grid points accepted: each is a full pass over the sample set per controller and task.
MAX_POINTS = 25
#: Largest span accepted: beyond it the knob reaches values no controller was built for.
MAX_SPAN = 1e3
#: Roles of the main run's point that make it an equal-effort point
#: (``snac_gym.evaluation.effort.matching.EffortRecord.role``).
EQUAL_EFFORT_ROLES = ("reference", "matched")

#: Columns of ``sweep.csv``.
SWEEP_COLUMNS = (
    "task",
    "controller",
    "knob",  # the controller's effort_parameter
    "knob_value",
    "grid_exponent",  # knob_value = default × span**grid_exponent (NaN: the main run's point off the grid)
    "main_run",  # the knob value of the main run
    "effort_role",  # the main run's role at that point (reference, matched, unmatched, fixed); "" elsewhere
    "equal_effort",  # main_run and the effort was matched (or is the reference's)
    "n",
    "cost",  # V/N under the run's --cost convention
    "cost_ci95",  # half width of its Student-t 95 % interval
    "cost_hjb",
    "cost_table1",
    "cost_table1_first",
    "success_rate",
    "qualified",  # success_rate ≥ the run's success_threshold
    "median_error",  # m; reach: median final error, track: median of the per-rollout median error over the 2nd half
    "max_abs_u_median",  # rad/s, median over rollouts of each rollout's peak |u|
    "max_abs_u_max",  # rad/s, the maximum |u| over the set (the ``max`` effort statistic)
    "median_peak_limit_fraction",
)


def knob_grid(default: float, points: int = DEFAULT_POINTS, span: float = DEFAULT_SPAN) -> np.ndarray:
    """``default × span ** linspace(−1, 1, points)``; the middle value is ``default`` exactly for odd ``points``.

    Raises:
        ValueError: If ``points`` is not in 2..:data:`MAX_POINTS`, ``span`` not in (1, :data:`MAX_SPAN`]
            or ``default`` not positive and finite.
    """
    check_grid(points, span)
    if not (math.isfinite(default) and default > 0):
        raise ValueError(f"the sweep needs a positive finite knob default, got {default}")
    exponents = np.linspace(-1.0, 1.0, points)
    return np.array([default if e == 0 else default * span**e for e in exponents])


def check_grid(points: int, span: float) -> None:
    """Raise ``ValueError`` (naming the CLI option) for a grid the sweep refuses."""
    if not 2 <= points <= MAX_POINTS:
        raise ValueError(f"--sweep-points must be between 2 and {MAX_POINTS}, got {points}")
    if not (math.isfinite(span) and 1.0 < span <= MAX_SPAN):
        raise ValueError(f"--sweep-span must be a number in (1, {MAX_SPAN:g}], got {span}")


def point_row(
    task: str,
    spec: ControllerSpec,
    value: float,
    exponent: float,
    rows: pd.DataFrame,
    role: str,
    success_threshold: float,
) -> dict[str, Any]:
    """One ``sweep.csv`` row from the per-rollout rows of one full pass."""
    costs = rows["cost"].to_numpy(dtype=float)
    half = math.nan
    if costs.size > 1:
        from scipy import stats  # ~0.5 s to import; the reports' prefetch thread loads it

        half = float(stats.t.ppf(0.975, costs.size - 1) * costs.std(ddof=1) / math.sqrt(costs.size))
    accuracy = rows[get_task(task).accuracy_measure]
    success_rate = float(rows["success"].mean())
    return {
        "task": task,
        "controller": spec.name,
        "knob": spec.knob,
        "knob_value": float(value),
        "grid_exponent": exponent,
        "main_run": bool(role),
        "effort_role": role,
        "equal_effort": role in EQUAL_EFFORT_ROLES,
        "n": len(rows),
        "cost": float(costs.mean()),
        "cost_ci95": half,
        "cost_hjb": float(rows["cost_hjb"].mean()),
        "cost_table1": float(rows["cost_table1"].mean()),
        "cost_table1_first": float(rows["cost_table1_first"].mean()),
        "success_rate": success_rate,
        "qualified": success_rate >= success_threshold,
        "median_error": float(accuracy.median()),
        "max_abs_u_median": float(rows["max_abs_u"].median()),
        "max_abs_u_max": float(rows["max_abs_u"].max()),
        "median_peak_limit_fraction": float(rows["peak_limit_fraction"].median()),
    }


def _main_points(config: EvaluationConfig, results: pd.DataFrame) -> dict[tuple[str, str], tuple[float, str]]:
    """The main run's knob value and effort role per (task, controller) (roles from its ``summary.csv``)."""
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    points: dict[tuple[str, str], tuple[float, str]] = {}
    for (task, controller), rows in results.groupby(["task", "controller"], sort=False):
        value = float(rows["effort_value"].iloc[0])
        column = f"{task}_effort_role"
        role = summary.loc[controller, column] if column in summary and controller in summary.index else ""
        points[(task, controller)] = (value, str(role) if isinstance(role, str) else "fixed")
    return points


def _sort_rows(rows: Sequence[dict[str, Any]], config: EvaluationConfig, names: Sequence[str]) -> pd.DataFrame:
    table = pd.DataFrame(list(rows), columns=list(SWEEP_COLUMNS))
    task_rank = {t: i for i, t in enumerate(config.tasks)}
    name_rank = {n: i for i, n in enumerate(names)}
    order = sorted(
        range(len(table)),
        key=lambda i: (
            task_rank[table["task"].iat[i]],
            name_rank[table["controller"].iat[i]],
            table["knob_value"].iat[i],
        ),
    )
    return table.iloc[order].reset_index(drop=True)


def run_sweep(config: EvaluationConfig, points: int = DEFAULT_POINTS, span: float = DEFAULT_SPAN) -> pd.DataFrame:
    """Run the evaluation of ``config``, then every controller over its effort knob; write the sweep's files.

    Args:
        config: The run (its ``out`` receives the main run's outputs, ``sweep.csv`` and
            ``tradeoff.png``; ``resume`` continues an interrupted run, sweep included).
        points: Grid points per controller and task (2..:data:`MAX_POINTS`).
        span: The grid reaches ``default/span`` … ``default·span`` (see :func:`knob_grid`).

    Returns:
        The ``sweep.csv`` table (:data:`SWEEP_COLUMNS`), sorted by task, controller (the run's
        order) and knob value.

    Raises:
        ValueError: On a bad grid or option (before anything runs), or as
            :func:`~snac_gym.evaluation.runner.run_evaluation` raises.
    """
    check_grid(points, span)
    config.validate()
    all_specs, _ = resolve_controllers(config)
    specs = [spec for spec in all_specs if spec.knob is not None and spec.knob_value is not None]
    if not specs:
        raise ValueError("--sweep: no evaluated controller declares an effort_parameter to sweep")
    for spec in specs:
        knob_grid(float(spec.knob_value), points, span)  # a bad default is refused before the main run
    results = run_evaluation(config)
    passes = _sweep_passes(config, specs, _main_points(config, results), points, span)
    kinematics = Kinematics(config.robot)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    # The main run's folder, reopened: same manifest, so its parts (the main run's points) are
    # found by run_passes instead of being recomputed, and the sweep's own parts resume alike.
    with RunStore(config.out, config.manifest(space, all_specs), resume=True) as store:
        # the controllers' passes alone: their workers load no kernel of the reference's
        with open_executor(config.workers, config.ray_address, evaluator_kernel_modules(reference=False)) as executor:
            samples = load_samples(config, kinematics, space, executor)
            progress = Progress(len(passes) * sum(len(samples[t]) for t in config.tasks), config.progress)
            evaluation = EvaluationRun(config, store, executor, samples, progress)
            rows = _run_points(evaluation, passes, [spec.name for spec in specs])
        sweep = _sort_rows(rows, config, [spec.name for spec in specs])
        summary = pd.read_csv(config.out / "summary.csv")
        if config.plots:
            plot_tradeoff(sweep, config, summary, config.out / "tradeoff.png", span)
        else:
            (config.out / "tradeoff.png").unlink(missing_ok=True)  # an earlier run's, not left stale
    return sweep


#: One point of the sweep: task, controller, knob value, grid exponent (NaN off the grid), main-run role.
SweepPoint = tuple[str, ControllerSpec, float, float, str]


def _sweep_passes(
    config: EvaluationConfig,
    specs: Sequence[ControllerSpec],
    main: dict[tuple[str, str], tuple[float, str]],
    points: int,
    span: float,
) -> list[SweepPoint]:
    """Every point of the sweep: the grid of each controller and task, and the main run's knob value."""
    passes: list[SweepPoint] = []
    for task in config.tasks:
        for spec in specs:
            grid = knob_grid(float(spec.knob_value), points, span)
            main_value, role = main[(task, spec.name)]
            values = {float(v): float(e) for v, e in zip(grid, np.linspace(-1.0, 1.0, points), strict=True)}
            values.setdefault(main_value, math.nan)
            for value in sorted(values):
                passes.append((task, spec, value, values[value], role if value == main_value else ""))
    return passes


def _run_points(evaluation: EvaluationRun, passes: Sequence[SweepPoint], names: Sequence[str]) -> list[dict[str, Any]]:
    """One full pass per point, concurrently; ``sweep.csv`` is rewritten as each point completes."""
    config, store = evaluation.config, evaluation.store
    rows: list[dict[str, Any]] = []
    lock = threading.Lock()

    def one_point(task: str, spec: ControllerSpec, value: float, exponent: float, role: str) -> None:
        # At the default, the arguments the main run used (no explicit knob): the same
        # part files, so a reference or --no-match-effort pass is read back, not rerun.
        kwargs = dict(spec.kwargs) if value == float(spec.knob_value) else {**spec.kwargs, spec.knob: value}
        (table,) = evaluation.run_passes([(task, spec, kwargs)])
        row = point_row(task, spec, value, exponent, table, role, config.success_threshold)
        with lock:  # each point is on disk as soon as it is done
            rows.append(row)
            csv = _sort_rows(rows, config, names).to_csv(index=False, float_format="%.17g")
            store.write_text("sweep.csv", csv)

    evaluation.progress.status("trade-off sweep")
    try:
        evaluation.concurrently([functools.partial(one_point, *p) for p in passes])
    finally:
        evaluation.progress.close()
    return rows


#: The three panels of a task's row in ``tradeoff.png``: x column, x label, log x axis.
_PANELS = (
    ("success_rate", "success rate", False),
    ("median_error", "median error, m ({})", True),
    ("max_abs_u_max", "peak effort: max |u| over the set, rad/s", False),
)


def plot_tradeoff(
    sweep: pd.DataFrame, config: EvaluationConfig, summary: pd.DataFrame | None, path: Path, span: float = DEFAULT_SPAN
) -> Path:
    """Draw ``tradeoff.png``: per task, V/N against success rate, median error and peak effort.

    One line per controller through its knob values in order; the main run's point is a star
    (an open diamond where its effort match failed), and points whose success rate is below
    ``config.success_threshold`` are hollow, so a cheap point that fails the task is told apart.
    """
    # only plotting needs matplotlib (~0.4 s; --no-plots skips it)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tasks = [t for t in config.tasks if (sweep["task"] == t).any()]
    names = list(dict.fromkeys(sweep["controller"]))
    colors = {name: f"C{i % 10}" for i, name in enumerate(names)}
    # Controllers with near-equal curves (SVF and DLS in regulation) would hide one another.
    styles = {name: ("-", "--", "-.", ":")[i % 4] for i, name in enumerate(names)}
    fig = Figure(figsize=(15, 4.4 * len(tasks) + 0.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(tasks), 3, squeeze=False)
    for row_axes, task in zip(axes, tasks, strict=True):
        part = sweep[sweep["task"] == task]
        target = _effort_target(summary, config, task)
        for ax, (column, label, log_x) in zip(row_axes, _PANELS, strict=True):
            for name in names:
                _draw_controller(
                    ax, part[part["controller"] == name].sort_values("knob_value"), column, colors[name], styles[name]
                )
            _finish_panel(ax, config, task, column, label, log_x, target)
        row_axes[0].set_title(f"{get_task(task).label} ({task})", loc="left", fontweight="bold")
    handles = _legend_handles(names, colors, styles, config.success_threshold)
    fig.legend(handles=handles, loc="lower center", ncol=min(6, len(handles)), frameon=False, fontsize=9)
    fig.suptitle(
        "Trade-off sweep: each controller over its effort knob "
        f"(default ÷{span:g} … ×{span:g}); lower is cheaper, lines follow the knob",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.07 + 0.02 / len(tasks), 1, 0.97))
    write_whole(path, lambda partial: fig.savefig(partial, dpi=110))
    return path


def _effort_target(summary: pd.DataFrame | None, config: EvaluationConfig, task: str) -> float:
    """The main run's ``max`` effort target of ``task`` (rad/s, drawn on the peak-effort panel), else NaN."""
    if summary is None or f"{task}_effort_target" not in summary or config.effort_statistic != "max":
        return math.nan
    targets = summary[f"{task}_effort_target"].dropna()
    return float(targets.iloc[0]) if len(targets) else math.nan


def _draw_controller(ax: Any, line: pd.DataFrame, column: str, color: str, style: str) -> None:
    """One controller's points in knob order, joined; marker by main-run role, hollow where it fails."""
    if line.empty:
        return
    x, y = line[column].to_numpy(float), line["cost"].to_numpy(float)
    ax.plot(x, y, style, color=color, alpha=0.7, lw=1.6, zorder=2)
    for xi, yi, qualified, main, equal in zip(
        x, y, line["qualified"], line["main_run"], line["equal_effort"], strict=True
    ):
        marker, size = ("*", 15) if equal else (("D", 8) if main else ("o", 6))
        face = color if qualified else "white"
        ax.plot(xi, yi, marker, ms=size, mfc=face, mec=color, mew=1.5, zorder=3)


def _finish_panel(
    ax: Any, config: EvaluationConfig, task: str, column: str, label: str, log_x: bool, target: float
) -> None:
    """Scales, the panel's reference line (success threshold, error tolerance or effort target) and labels."""
    ax.set_yscale("log")
    if log_x:
        ax.set_xscale("log")
    tolerance = get_task(task).success_tolerance
    if column == "success_rate":
        ax.axvline(config.success_threshold, color="0.4", ls="--", lw=1)
        ax.set_xlim(-0.03, 1.03)
    elif column == "median_error":
        ax.axvline(tolerance, color="0.4", ls=":", lw=1)
    elif math.isfinite(target):
        ax.axvline(target, color="0.4", ls="--", lw=1)
    what = get_task(task).accuracy_text
    ax.set_xlabel(label.format(what))
    ax.set_ylabel(f"V/N ({config.cost} cost)")
    ax.grid(True, which="both", alpha=0.25)


def _legend_handles(
    names: Sequence[str], colors: dict[str, str], styles: dict[str, str], threshold: float
) -> list[Any]:
    """One entry per controller, then the markers' and reference lines' meanings."""
    from matplotlib.lines import Line2D  # only plotting needs matplotlib

    handles = [Line2D([], [], color=colors[n], ls=styles[n], marker="o", label=controller_label(n)) for n in names]
    handles += [
        Line2D([], [], ls="", marker="*", ms=13, color="0.3", label="equal-effort point (main run)"),
        Line2D([], [], ls="", marker="D", ms=7, mfc="white", color="0.3", label="main run, effort unmatched"),
        Line2D([], [], ls="", marker="o", mfc="white", color="0.3", label=f"hollow: success < {threshold:.0%}"),
        Line2D([], [], ls="--", color="0.4", label="success threshold / effort target"),
        Line2D([], [], ls=":", color="0.4", label="success tolerance (1 mm reach, 5 mm track)"),
    ]
    return handles


__all__ = ["DEFAULT_POINTS", "DEFAULT_SPAN", "MAX_POINTS", "SWEEP_COLUMNS", "knob_grid", "plot_tradeoff", "run_sweep"]
