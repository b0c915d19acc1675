"""A training run's log read back (evaluations.csv, SB3's progress.csv of every segment) and its training curves
(success rate, mean trajectory cost and training reward against timesteps) of :func:`snac_gym.ppo.train.train_ppo`."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from snac_gym.common.outputs import write_whole
from snac_gym.tasks import get_task

__all__ = ["plot_training_curves", "read_evaluations", "read_training_log", "training_curves_figure"]


def read_evaluations(out: str | Path) -> list[dict[str, float]]:
    """The rows of a run folder's evaluations.csv, in order (none if it has no evaluation yet)."""
    path = Path(out) / "evaluations.csv"
    if not path.exists():
        return []
    with path.open() as handle:
        return [{k: float(v) for k, v in row.items() if v != ""} for row in csv.DictReader(handle)]


def read_training_log(out: str | Path) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """The evaluation rows and the SB3 progress rows (all segments, in order) of a run folder."""
    out = Path(out)
    evaluations = read_evaluations(out)
    progress: list[dict[str, float]] = []
    segments = sorted((out / "logs").glob("segment_*"), key=lambda p: int(p.name.split("_")[1]))
    for segment in segments:
        path = segment / "progress.csv"
        if path.exists() and path.stat().st_size:
            with path.open() as handle:
                rows = csv.DictReader(handle)
                progress += [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in rows]
    return evaluations, progress


def plot_training_curves(out: str | Path, path: str | Path | None = None, title: str | None = None) -> Path:
    """Plot success rate, mean trajectory cost and training reward against timesteps into a PNG.

    Args:
        out: A run folder of :func:`train_ppo`.
        path: Where to write (default ``OUT/training_curves.png``).
        title: Figure title (default: task and seed from ``OUT/config.json``).

    Returns:
        The path written.
    """
    import matplotlib  # only plotting needs matplotlib; the trainer does not

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    out = Path(out)
    fig = training_curves_figure(out, title)
    target = Path(path) if path is not None else out / "training_curves.png"
    target.parent.mkdir(parents=True, exist_ok=True)
    write_whole(target, lambda partial: fig.savefig(partial, dpi=110))
    plt.close(fig)
    return target


def _timesteps_axis(axis: Any) -> None:
    """Label the x axis of ``axis`` in engineering notation (``200k``, ``1.2M``) with at most 5 ticks.

    Plain integers (``100000``, ``200000``, ...) on a third of a 13-inch figure run into each other.
    """
    from matplotlib.ticker import EngFormatter, MaxNLocator  # only plotting needs matplotlib

    axis.xaxis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
    axis.xaxis.set_major_formatter(EngFormatter(sep=""))


def training_curves_figure(out: str | Path, title: str | None = None) -> Any:
    """The figure of :func:`plot_training_curves` (three panels against timesteps), not saved.

    Args:
        out: A run folder of :func:`train_ppo` (``config.json``, ``evaluations.csv``, ``logs/``).
        title: Figure title (default: task and seed from ``OUT/config.json``).

    Returns:
        The matplotlib figure; the caller closes it.
    """
    import matplotlib.pyplot as plt  # only plotting needs matplotlib

    out = Path(out)
    config = json.loads((out / "config.json").read_text())
    evaluations, progress = read_training_log(out)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    if evaluations:
        steps = [row["timesteps"] for row in evaluations]
        for key in [k for k in evaluations[0] if k.startswith("success_rate_")]:
            axes[0].plot(
                steps,
                [100 * row[key] for row in evaluations],
                lw=1,
                alpha=0.7,
                label=f"at {key.removeprefix('success_rate_')}",
            )
        axes[0].plot(
            steps,
            [100 * row["success_rate"] for row in evaluations],
            marker="o",
            ms=3,
            color="k",
            label="at every horizon",
        )
        best_rows = [row for row in evaluations if row.get("is_best")]
        if best_rows:  # the model kept in best/: the last row that improved
            best = best_rows[-1]
            axes[0].plot(
                [best["timesteps"]], [100 * best["success_rate"]], "*", ms=12, color="C3", label="kept (best/)"
            )
            axes[1].plot([best["timesteps"]], [best["mean_cost"]], "*", ms=12, color="C3")
        axes[0].legend(fontsize=8, loc="lower right")
        axes[1].plot(steps, [row["mean_cost"] for row in evaluations], marker="o", ms=3)
        axes[1].set_yscale("log")
    threshold_mm = 1000 * float(config["evaluation"]["success_error_m"])
    spec = get_task(config["task"])
    criterion = "final ‖e‖ ≤" if spec.success_measure == "final_error" else "mean ‖e‖, 2nd half ≤"
    axes[0].set(
        xlabel="timesteps", ylabel="success rate, %", ylim=(-2, 102), title=f"success ({criterion} {threshold_mm:g} mm)"
    )
    first_horizon = float(config["evaluation"]["horizons_s"][0])
    axes[1].set(xlabel="timesteps", ylabel="mean trajectory cost V", title=f"Table I cost V over {first_horizon:g} s")
    rewards = [
        (row["time/total_timesteps"], row["rollout/ep_rew_mean"])
        for row in progress
        if "rollout/ep_rew_mean" in row and "time/total_timesteps" in row
    ]
    if rewards:
        axes[2].plot(*zip(*rewards))
    else:  # runs made before the batched env was wrapped in VecMonitor logged no episode returns
        axes[2].text(0.5, 0.5, "no episode returns logged", ha="center", va="center", transform=axes[2].transAxes)
        axes[2].set_xlim(axes[0].get_xlim())
        axes[2].set_yticks([])
    reward = config.get("reward", {})
    reward_name = {"shaped": "shaped", "env": "the env's"}.get(reward.get("type", "shaped"))
    if reward_name is None:  # minus the evaluator's cost under the run's convention
        reward_name = f"−{reward.get('cost', 'hjb')} cost, Q = {float(reward.get('q_scale', 1.0)):g}·I"
    axes[2].set(xlabel="timesteps", ylabel="mean episode return", title=f"training reward ({reward_name})")
    for axis in axes:
        axis.grid(alpha=0.3)
        _timesteps_axis(axis)
    if title is None:
        title = f"PPO, task {config['task']}, seed {config['seed']}"
        if (out / "state.json").exists():
            state = json.loads((out / "state.json").read_text())
            title += f": {state['timesteps']} timesteps, {state['wall_time_s'] / 60:.1f} min wall time"
    fig.suptitle(title)
    fig.tight_layout()
    return fig
