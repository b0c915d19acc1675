"""The reports of a run: ``summary.md`` (Table I's layout and the details behind it) and the box plots.

:func:`write_reports` writes ``summary.csv`` (the table of :mod:`snac_gym.evaluation.reports.summary`),
``summary.md`` (:func:`summary_markdown`, one helper per section) and ``cost_boxplot.png``
(:func:`plot_cost_boxes`).

Its sections live beside it, each importable from here: :mod:`~snac_gym.evaluation.reports.tables` (the tables),
:mod:`~snac_gym.evaluation.reports.optimality_section` (the optimality gap) and
:mod:`~snac_gym.evaluation.reports.plots` (the box plots); this module keeps the text around them (introduction,
effort matching, closing lines) and the writing of the files.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd
from snac_gym.evaluation.effort.matching import MODEL_ORIGIN
from snac_gym.evaluation.execution.passes import SIDE_BY_SIDE
from snac_gym.evaluation.reports.optimality_section import optimality_markdown
from snac_gym.evaluation.reports.plots import plot_cost_boxes, prefetch_report_modules
from snac_gym.evaluation.reports.summary import controller_label, summarise
from snac_gym.evaluation.reports.tables import (
    OVERVIEW_COLUMNS,
    convention_lines,
    critic_lines,
    general_number,
    number,
    overview_lines,
    paired_lines,
    table_one_lines,
    task_detail_lines,
)

from snac_gym.common.outputs import write_text_whole, write_whole
from snac_gym.tasks import get_task

__all__ = [
    "OVERVIEW_COLUMNS",
    "optimality_markdown",
    "overview_lines",
    "paired_lines",
    "plot_cost_boxes",
    "prefetch_report_modules",
    "summary_markdown",
    "write_reports",
]


def summary_markdown(
    summary: pd.DataFrame,
    config: Any,
    efforts: Sequence[Any],
    skipped: dict[str, str],
    effort_statistic: str,
    timings: dict[str, float] | None = None,
    executor: str = "",
    results: pd.DataFrame | None = None,
    machine: str = "",
) -> str:
    """``summary.md``: Table I's layout, the details behind it, the effort matching and the plot; ``machine``: the
    machine the wall time was measured on, one line (:func:`~snac_gym.common.machine.describe_machine`)."""
    tasks = [t for t in config.tasks if f"{t}_cost" in summary]
    lines = _introduction_lines(summary, config, tasks, effort_statistic)
    lines += _calibration_source_lines(efforts)  # before the first table: the command prints up to its first "##"
    lines += overview_lines(summary, tasks)
    lines += ["", "## Table I, in the paper's layout", ""]
    lines += table_one_lines(summary, tasks)
    lines += convention_lines(summary, tasks, config.convention.q_scale)
    lines += paired_lines(summary, tasks)
    lines += critic_lines(summary, tasks)
    for t in tasks:
        lines += task_detail_lines(summary, t)
    if results is not None:
        lines += optimality_markdown(summary, results, tasks)
    lines += _effort_lines(summary, config, efforts, effort_statistic)
    lines += _closing_lines(skipped, timings, executor, getattr(config, "plots", True), machine)
    return "\n".join(lines)


def _effort_set_text(config: Any) -> str:
    size = getattr(config, "effort_set_size", None)
    engine = getattr(config, "engine", "kinematic")
    model = "" if engine == "kinematic" else f", on the kinematic model (the reported rollouts are {engine}'s)"
    if size is None:
        return model
    return model + (
        f", on the first {size} samples of the seed (`--effort-samples`; the efforts in the effort table are "
        "theirs), so that the matched knobs do not depend on how many samples are evaluated"
    )


def _introduction_lines(summary: pd.DataFrame, config: Any, tasks: Sequence[str], effort_statistic: str) -> list[str]:
    """The title, what was run and scored, and what success and accuracy mean."""
    n_text = ", ".join(f"{int(summary[f'{t}_n'].max())} {get_task(t).label.lower()} samples" for t in tasks)
    horizons = ", ".join(f"{t} {config.steps(t)} steps ({config.steps(t) * config.dt:g} s)" for t in tasks)
    threshold = getattr(config, "success_threshold", 0.95)
    return [
        "# Trajectory cost V/N (Table I of the paper)",
        "",
        f"Engine `{config.engine}`, {n_text}, seed {config.seed}, Δt = {config.dt:g} s, horizons: {horizons}. "
        f"{config.convention.describe()}; V/N is the mean over samples, "
        "± its standard deviation, with the 95 % bootstrap percentile interval of the mean (seeded; the paired "
        "medians below are the comparison one heavy-tailed sample cannot move). "
        + (
            "Equal effort: " + effort_statistic + " matched (table below)" + _effort_set_text(config) + "."
            if config.match_effort
            else "No effort matching (each controller at its own settings)."
        ),
        "",
        (
            "Success: " + "; ".join(f"{t}: {get_task(t).success_text()}" for t in tasks) + ". "
            f"Only controllers with a success rate of at least {threshold:.0%} on a "
            "task are ranked there (rank, ratio to the best, ratio to SNAC); the others are marked **fails** and are "
            "never ranked, whatever their cost. Accuracy: median final error (reach) or median over samples of the "
            "median error over the second half (track)."
        ),
        "",
    ]


def _calibration_source_lines(efforts: Sequence[Any]) -> list[str]:
    """Where the knobs came from when this run did not match them (the calibration cache)."""
    sources = sorted({e.calibrated_by for e in efforts if getattr(e, "calibrated_by", "")})
    if not sources:
        return []
    if sources == [MODEL_ORIGIN]:
        return [
            "**The knobs were matched on the kinematic model**: a run in a physics engine matches its effort on the "
            "exact model θₖ₊₁ = θₖ + uₖΔt over the effort set (Table I's V/N in the three engines agree within "
            "0.75 % at the same knobs, docs/physics.md), then runs the reported samples in its engine at those "
            "knobs (the efforts and targets below are the model's, on the effort set). A kinematic run at the same "
            "settings would match the same knobs, and reads these from the calibration cache.",
            "",
        ]
    if any(source.startswith("the knobs shipped") for source in sources):
        return [
            "**The knobs were not matched by this run**: they are the knobs shipped with snac-gym for these "
            "default settings, matched on the same 1000-sample effort set (`python tools/ship_calibration.py`; the "
            "test suite recomputes them with the current code and fails when one moves; the efforts and targets "
            "below are that run's, on the effort set). `--recalibrate` matches them anew.",
            "",
        ]
    return [
        f"**The knobs were not matched by this run**: they come from the calibration cache, matched by "
        f"{' and '.join(sources)} on the same effort set, settings and code (the efforts and targets below are "
        "that run's, on the effort set). `--recalibrate` matches them anew.",
        "",
    ]


def _effort_lines(summary: pd.DataFrame, config: Any, efforts: Sequence[Any], effort_statistic: str) -> list[str]:
    """How each controller's effort was set, both effort statistics, and a warning for unmatched ones."""
    lines = [
        "",
        "## Control effort",
        "",
        f"Statistic: {effort_statistic}; tolerance {config.effort_tolerance:.0%} of the target."
        if config.match_effort
        else f"Statistic (not matched): {effort_statistic}.",
        "",
        *_calibration_source_lines(efforts),
        (
            "Both statistics of every controller's rollouts, whichever was matched: the maximum |u| over the "
            "sample set (rad/s) and the median over samples of each rollout's peak |u_j|/ū_j."
        ),
        "",
        (
            "| Task | Controller | role | knob | value | effort | target | max \\|u\\| over the set (rad/s) "
            "| median peak \\|u\\|/ū | passes | note |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    by_controller = summary.set_index("controller")
    for e in efforts:
        row = by_controller.loc[e.controller] if e.controller in by_controller.index else {}
        literal_max = row.get(f"{e.task}_max_abs_u", math.nan)
        median_peak = row.get(f"{e.task}_median_peak_limit_fraction", math.nan)
        lines.append(
            f"| {e.task} | {controller_label(e.controller)} | {e.role} | {e.knob or '—'} | "
            f"{general_number(e.knob_value)} | {number(e.effort, 4)} | {number(e.target, 4)} | "
            f"{number(literal_max, 4)} | {number(median_peak, 4)} | {e.passes} | {e.note} |"
        )
    unmatched = [e for e in efforts if e.role == "unmatched"]
    if unmatched:
        lines += [
            "",
            "**Warning:** effort not matched for " + ", ".join(f"{e.controller} ({e.task})" for e in unmatched) + ".",
        ]
    return lines


#: The heading of summary.md's list of the registered controllers a run left out (``snac-gym evaluate`` repeats the
#: list on stderr).
LEFT_OUT_HEADING = "Registered controllers left out:"


def _closing_lines(
    skipped: dict[str, str], timings: dict[str, float] | None, executor: str, plots: bool = True, machine: str = ""
) -> list[str]:
    """The controllers left out, the wall time, and the box plot (when it is drawn)."""
    lines: list[str] = []
    if skipped:
        lines += ["", LEFT_OUT_HEADING, ""] + [f"- `{name}`: {reason}" for name, reason in skipped.items()]
    if timings:
        phases = ", ".join(
            f"{name} {seconds:.1f} s" for name, seconds in timings.items() if name not in ("total", SIDE_BY_SIDE)
        )
        if SIDE_BY_SIDE in timings:  # the two phases' times overlap: say so, and how long they took together
            phases += f"; the passes and the optimal reference side by side, {timings[SIDE_BY_SIDE]:.1f} s in all"
        lines += [
            "",
            (
                f"Wall time {timings.get('total', math.nan):.1f} s on {executor} ({phases}); "
                "a resumed run counts only its own time."
                + (f" Machine: {machine} at the start (`machine.json`)." if machine else "")
            ),
        ]
    return lines + (["", "![Per-sample trajectory cost](cost_boxplot.png)", ""] if plots else [""])


def write_reports(
    root: Path,
    results: pd.DataFrame,
    efforts: Sequence[Any],
    config: Any,
    skipped: dict[str, str],
    effort_statistic: str,
    timings: dict[str, float] | None = None,
    executor: str = "",
    machine: str = "",
) -> pd.DataFrame:
    """Write ``summary.csv``, ``summary.md`` and ``cost_boxplot.png`` into ``root`` (the figure only
    where ``config.plots``; else one left by an earlier run of the folder is removed, not left stale)."""
    controllers = list(dict.fromkeys(results["controller"]))
    tasks = [t for t in config.tasks if (results["task"] == t).any()]
    threshold = getattr(config, "success_threshold", 0.95)
    summary = summarise(results, efforts, tasks, controllers, threshold, config.convention)
    write_whole(root / "summary.csv", lambda path: summary.to_csv(path, index=False, float_format="%.10g"))
    write_text_whole(
        root / "summary.md",
        summary_markdown(summary, config, efforts, skipped, effort_statistic, timings, executor, results, machine),
    )
    if getattr(config, "plots", True):
        plot_cost_boxes(results, tasks, controllers, root / "cost_boxplot.png", threshold)
    else:
        (root / "cost_boxplot.png").unlink(missing_ok=True)
    return summary
