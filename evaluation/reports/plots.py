"""The reports' figure, the per-sample cost box plots, and the early import of what the reports need.

Part of :mod:`snac_gym.evaluation.reports.writer`; matplotlib is imported only when a figure is drawn (every worker
imports the reports' modules, none plots).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from snac_gym.evaluation.reference.optimum import OPTIMAL

from snac_gym.common.outputs import write_whole
from snac_gym.tasks import get_task

__all__ = ["plot_cost_boxes", "prefetch_report_modules"]


def prefetch_report_modules(plots: bool = True) -> threading.Thread:
    """Import what the reports need (scipy.stats, and matplotlib's pyplot where they draw: 1-2 s) in a daemon thread
    and return it.

    A run calls this when its last phase starts: its main process then mostly waits for the workers,
    and the reports, written by it alone after the last job, do not begin with these imports. A run without
    plots (``--no-plots``) never imports matplotlib.
    """

    def load() -> None:
        try:
            import scipy.stats  # noqa: F401  (in this thread, off the main one: the point of it)

            if plots:
                import matplotlib  # only for a run that draws, in this thread too

                matplotlib.use("Agg")
                import matplotlib.pyplot  # noqa: F401  (after the backend is chosen)
        except ImportError:  # the reports' own import says what is missing
            pass

    thread = threading.Thread(target=load, name="snac-gym report imports", daemon=True)
    thread.start()
    return thread


def plot_cost_boxes(
    results: pd.DataFrame, tasks: Sequence[str], controllers: Sequence[str], path: Path, success_threshold: float = 0.95
) -> Path:
    """Box plots of the per-sample cost, one panel per task, log scale; controllers that fail the
    task (success below ``success_threshold``) are drawn hatched and labelled so."""
    import matplotlib  # start-up time: each worker imports this module, never plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    fig, axes = plt.subplots(len(tasks), 1, figsize=(1.5 + 0.9 * len(controllers), 3.6 * len(tasks)), squeeze=False)
    for ax, task in zip(axes[:, 0], tasks, strict=True):
        data, labels, failing = [], [], []
        for controller in controllers:
            part = results.loc[(results["task"] == task) & (results["controller"] == controller)]
            if len(part):
                data.append(part["cost"].to_numpy())
                fails = controller != OPTIMAL and part["success"].mean() < success_threshold
                failing.append(fails)
                labels.append(("optimum" if controller == OPTIMAL else controller) + ("\n(fails)" if fails else ""))
        boxes = ax.boxplot(data, showmeans=True, patch_artist=True)
        for box, fails in zip(boxes["boxes"], failing, strict=True):
            box.set(facecolor="white", hatch="///" if fails else None, edgecolor="0.5" if fails else "black")
        ax.set_xticks(range(1, len(labels) + 1), labels)
        if all(np.all(d > 0) for d in data):
            ax.set_yscale("log")
        ax.set_title(f"{get_task(task).label} ({task}), ▲ mean")
        ax.set_ylabel("trajectory cost V per sample")
        ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    write_whole(path, lambda partial: fig.savefig(partial, dpi=110))
    plt.close(fig)
    return path
