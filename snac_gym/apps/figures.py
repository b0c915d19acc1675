"""A run's figures: the Figure 3 panels of a demo or a real run (and a real run's loop timing), drawn when the run
ends or later from its log (``snac-gym plot``).

Each figure is drawn whole or not at all; an interrupt stops the drawing and says how many were drawn, so that a run
cut while drawing can draw the rest from its log.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.rollout import read_log
from snac_gym.tasks import get_task

__all__ = ["LOG_SUFFIX", "demo_figures", "draw_figures", "redraw_figures", "run_log", "timing_figure"]

#: How a run's log is named: ``{task}_{controller}_log.parquet`` (its files share the prefix before it).
LOG_SUFFIX = "log.parquet"


def demo_figures(log: pd.DataFrame, tolerance: float) -> dict[str, Callable[[], Any]]:
    """The Figure 3 panels of one run, by name: each a function that draws its figure (the critic's weights, the
    HJB residual and the model's correction where the log has them)."""
    from snac_gym.apps import plots as panels  # matplotlib only when plotting (--no-plots)

    drawers: dict[str, Callable[[], Any]] = {
        "path": lambda: panels.plot_path(log),
        "error": lambda: panels.plot_error(log, tolerance=tolerance),
        "joint_velocities": lambda: panels.plot_joint_velocities(log),
        "cost": lambda: panels.plot_cost(log),
        "figure3": lambda: panels.plot_figure3(log, tolerance=tolerance),
    }
    if "w_0" in log.columns:
        drawers["critic_weights"] = lambda: panels.plot_critic_weights(log)
    if "hjb_ratio" in log.columns:
        drawers["optimality"] = lambda: panels.plot_optimality(log)
    if "model_residual" in log.columns:
        drawers["model"] = lambda: panels.plot_model_correction(log)
    return drawers


def timing_figure(periods_ms: np.ndarray, dt: float) -> dict[str, Callable[[], Any]]:
    """A real run's loop timing (its control periods, ms), by name; none for a run without periods."""
    if not len(periods_ms):
        return {}
    from snac_gym.apps.plots import plot_loop_timing  # matplotlib only when plotting

    return {"timing": lambda: plot_loop_timing(periods_ms, dt)}


def draw_figures(
    drawers: Mapping[str, Callable[[], Any]],
    out: Path,
    prefix: str,
    before: Callable[[], None] | None = None,
    kept: str | None = None,
    log: Path | None = None,
    say: Callable[[str], object] | None = None,
) -> list[Path]:
    """Draw each figure into ``out/{prefix}{name}.png``, whole or not at all; ``before`` runs first (it may raise).
    ``say`` hears first how many are drawn where (a second or more each, with matplotlib's import).

    An interrupt (``KeyboardInterrupt``) stops the drawing and says in ``exc.kept`` (after ``kept``, by default that
    the run's log and summary, written before, are complete) how many were drawn and the command that draws them all
    from the log (``log``, default ``out/{prefix}log.parquet``)."""
    from snac_gym.apps.plots import save_figure  # matplotlib only when plotting (--no-plots)

    files: list[Path] = []
    if say is not None:
        say(f"drawing {len(drawers)} figures into {out}/")
    try:
        if before is not None:
            before()
        for name, draw in drawers.items():
            files.append(save_figure(draw(), out / f"{prefix}{name}.png"))
    except KeyboardInterrupt as exc:
        said = f"the log and summary are complete in {out}/; " if kept is None else kept
        exc.kept = (  # type: ignore[attr-defined]
            f"{said}{len(files)} of {len(drawers)} figures were drawn (each whole); "
            f"`snac-gym plot {log or out / (prefix + LOG_SUFFIX)}` draws them all"
        )
        raise
    return files


def run_log(path: str | Path) -> Path:
    """The log ``path`` names: a ``*_log.parquet`` file, or a folder holding exactly one.

    Raises:
        ValueError: If there is no such file, the folder holds none or several, or the name is not a log's.
    """
    path = Path(path)
    if path.is_dir():
        logs = sorted(path.glob(f"*_{LOG_SUFFIX}"))
        if len(logs) != 1:
            found = ", ".join(p.name for p in logs) if logs else "none"
            # An evaluation's folder holds rows, not a log: evaluate draws its box plots itself, with its reports.
            evaluation = not logs and (path / "run.json").is_file() and (path / "results.parquet").is_file()
            hint = " (an evaluation's folder: evaluate drew its box plots; plot draws a demo's or a real run's log)"
            raise ValueError(
                f"{path}/ must hold one run's log (*_{LOG_SUFFIX}) to draw; found {found}{hint if evaluation else ''}"
            )
        return logs[0]
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if not path.name.endswith(f"_{LOG_SUFFIX}"):
        beside = path.with_suffix(".parquet")  # --csv writes the CSV log beside the Parquet one, which plot reads
        csv_log = path.suffix == ".csv" and beside.name.endswith(f"_{LOG_SUFFIX}") and beside.is_file()
        hint = f"; draw the Parquet log beside it: `snac-gym plot {beside}`"
        raise ValueError(f"{path} is not a run's log: its name must end in _{LOG_SUFFIX}{hint if csv_log else ''}")
    return path


def redraw_figures(
    path: str | Path, out: str | Path | None = None, say: Callable[[str], object] | None = None
) -> list[Path]:
    """Draw a demo's or a real run's figures from its log (``path``: the log or its folder, :func:`run_log`), into
    ``out`` (default: the log's folder), as the run would have drawn them.

    The success tolerance the figures mark is the run's summary's (``*_summary.json`` beside the log), else the
    task's; a real run's loop timing is drawn from its ``*_timing.csv`` where it is beside the log. ``say`` hears
    how many figures are drawn where, before the first (:func:`draw_figures`).

    Raises:
        ValueError: For a path that is no log (:func:`run_log`) or a file that is not one.
    """
    log_path = run_log(path)
    try:
        log = read_log(log_path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several kinds for a file that is not Parquet
        raise ValueError(f"{log_path} is not a run's log: {type(exc).__name__}: {exc}") from None
    if "task" not in log.attrs or "dt" not in log.attrs:
        raise ValueError(f"{log_path} is not a run's log: it has no task or dt (written by demo or real)")
    prefix = log_path.name.removesuffix(LOG_SUFFIX)
    folder = log_path.parent
    summary = folder / f"{prefix}summary.json"
    try:
        tolerance = json.loads(summary.read_text()).get("tolerance") if summary.exists() else None
    except ValueError as exc:  # a damaged summary: named, not a bare JSON error
        raise ValueError(f"{summary} (the run's summary, for its tolerance) is not JSON: {exc}") from None
    if tolerance is None:
        tolerance = get_task(str(log.attrs["task"])).success_tolerance
    drawers = demo_figures(log, float(tolerance))
    timing = folder / f"{prefix}timing.csv"
    if timing.exists():
        periods = pd.read_csv(timing)["period_ms"].to_numpy()
        drawers.update(timing_figure(periods, float(log.attrs["dt"])))
    target = folder if out is None else Path(out)
    target.mkdir(parents=True, exist_ok=True)
    return draw_figures(drawers, target, prefix, kept=f"in {target}/: ", log=log_path, say=say)
