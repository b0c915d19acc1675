"""Figure panels of a trajectory log (the paper's Figure 3, plus the critic weights).

Every function takes a log from :func:`snac_gym.rollout.rollout` and returns a
:class:`matplotlib.figure.Figure` drawn on the Agg canvas: no pyplot, no display, no global
state, so plots are safe in tests, CI and worker processes. :func:`save_figure` writes PNGs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator, SymmetricalLogLocator

from snac_gym.common.outputs import write_whole
from snac_gym.control.cost import cost_rates
from snac_gym.references import Ellipse, FixedTarget
from snac_gym.rollout import log_array
from snac_gym.tasks import TASKS

_COLOURS = ["C0", "C1", "C2", "C3", "C4", "C5", "C6", "C7", "C8", "C9"]


def _figure(width: float = 6.4, height: float = 4.8) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _reference_points(log: pd.DataFrame, count: int = 256) -> np.ndarray | None:
    """Points of the whole reference (target, or the full ellipse) from the log's metadata."""
    spec = log.attrs.get("reference")
    if not spec:
        return None
    if "target" in spec:
        return FixedTarget(spec["target"]).points()
    return Ellipse.from_dict(spec).points(count)


def plot_path(log: pd.DataFrame, ax: Any = None) -> Figure:
    """End-effector path against the reference in 3-D (Figure 3 a/e)."""
    fig = ax.figure if ax is not None else _figure()
    ax = ax if ax is not None else fig.add_subplot(projection="3d")
    x, x_d = log_array(log, "x"), log_array(log, "x_d")
    points = _reference_points(log)
    fixed = np.allclose(x_d, x_d[:1])
    if points is not None and len(points) > 1 and not fixed:
        # The whole ellipse: in the paper's 20 s x_d covers only part of it, which alone does not show the curve.
        closed = np.vstack([points, points[:1]])
        ax.plot(*closed.T, color="0.55", lw=1.2, label="reference ellipse (whole)")
    if fixed:
        ax.scatter(*x_d[0], color="C3", marker="*", s=120, label="target")
    else:
        ax.plot(*x_d.T, color="C1", lw=2.0, ls="--", label=f"desired $x_d(t)$, 0–{log['t'].iloc[-1]:.0f} s")
    ax.plot(*x.T, color="C0", lw=1.8, label="end effector $x(t)$")
    ax.scatter(*x[0], color="C0", marker="o", s=25, label="start")
    for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y"), (ax.zaxis, "z")):
        axis.set_major_locator(MaxNLocator(4))  # the default's 7-9 labels run into each other on a 3-D axis
        axis.set_tick_params(labelsize="small")
        axis.set_label_text(f"{name} (m)")
    ax.set_title("End-effector path")
    # Below the axes: inside, it covered the path's corner.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=2, fontsize="small", frameon=False)
    return fig


#: The error components' names by task dimension: position, then the orientation's rotation-vector components.
ERROR_COMPONENTS = {3: ["x", "y", "z"], 6: ["x", "y", "z", "rx", "ry", "rz"]}


def plot_error(log: pd.DataFrame, axes: Any = None, tolerance: float | None = None) -> Figure:
    """Error components vs time, and its norm on a log scale (Figure 3 b/f)."""
    fig = axes[0].figure if axes is not None else _figure(6.4, 5.6)
    top, bottom = axes if axes is not None else fig.subplots(2, 1, sharex=True)
    t, e = log["t"].to_numpy(), log_array(log, "e")
    names = ERROR_COMPONENTS.get(e.shape[1], [str(i) for i in range(e.shape[1])])
    for i in range(e.shape[1]):
        top.plot(t, e[:, i], color=_COLOURS[i % 10], label=f"$e_{{{names[i]}}}$")
    top.set_ylabel("error (m)")
    top.set_title("Task-space error $e = x - x_d$")
    top.legend(fontsize="small")
    top.grid(alpha=0.3)
    norm = np.linalg.norm(e, axis=1)
    bottom.semilogy(t, np.maximum(norm, 1e-9), color="k", label=r"$\|e\|$")
    if tolerance is not None:
        bottom.axhline(tolerance, color="C3", ls="--", lw=1.0, label=f"{tolerance * 1e3:g} mm")
    bottom.set_xlabel("time (s)")
    bottom.set_ylabel(r"$\|e\|$ (m)")
    bottom.legend(fontsize="small")
    bottom.grid(alpha=0.3, which="both")
    return fig


def plot_joint_velocities(log: pd.DataFrame, ax: Any = None) -> Figure:
    """Joint-velocity commands vs time with their limits (Figure 3 c/g)."""
    fig = ax.figure if ax is not None else _figure()
    ax = ax if ax is not None else fig.add_subplot()
    t, u = log["t"].to_numpy(), log_array(log, "u")
    limits = log.attrs.get("velocity_limits")
    for j in range(u.shape[1]):
        colour = _COLOURS[j % 10]
        ax.plot(t, u[:, j], color=colour, label=f"$u_{j}$")
        if limits is not None:
            ax.axhline(limits[j], color=colour, ls="--", lw=0.8, alpha=0.6)
            ax.axhline(-limits[j], color=colour, ls="--", lw=0.8, alpha=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("joint velocity (rad/s)")
    ax.set_title("Joint velocities and their limits")
    handles, _ = ax.get_legend_handles_labels()
    if limits is not None:
        handles.append(Line2D([], [], color="0.4", ls="--", lw=0.8, label="±limit (the joint's colour)"))
    ax.legend(handles=handles, ncol=3, fontsize="small")
    ax.grid(alpha=0.3)
    return fig


def plot_cost(log: pd.DataFrame, axes: Any = None, Q: np.ndarray | None = None, R: np.ndarray | None = None) -> Figure:
    """Cost vs time (Figure 3 d/h): the instantaneous cost and the running trajectory cost.

    Top: ``eₖᵀQeₖ + uₖᵀRuₖ`` (integrand of eq. 6). Bottom: the running sums of the three terms
    of the evaluator's trajectory cost ``V = Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt`` (u₋₁ = 0), both
    from :mod:`snac_gym.control.cost`. The total is a thin dashed line over the terms, so that a term that
    makes up nearly all of it stays visible under it.

    Args:
        log: A demo log (columns ``t``, ``e_*``, ``u_*``; ``attrs["dt"]`` the control period).
        axes: Two axes (top, bottom) to draw into; a new figure when ``None``.
        Q: Error weight (default identity).
        R: Effort weight (default identity).

    Returns:
        The figure drawn into.
    """
    fig = axes[0].figure if axes is not None else _figure(6.4, 5.6)
    top, bottom = axes if axes is not None else fig.subplots(2, 1, sharex=True)
    t = log["t"].to_numpy()
    dt = float(log.attrs.get("dt", t[1] - t[0] if len(t) > 1 else 1.0))
    rates = cost_rates(log_array(log, "e"), log_array(log, "u"), dt, Q, R)
    top.semilogy(t, np.maximum(rates.error + rates.effort, 1e-12), color="k")
    top.set_ylabel(r"$e^TQe + u^TRu$")
    top.set_title("Instantaneous cost (eq. 6 integrand)")
    top.grid(alpha=0.3, which="both")
    for name, values, colour in (
        ("error", rates.error, "C0"),
        ("effort", rates.effort, "C1"),
        ("smoothness", rates.smoothness, "C2"),
    ):
        bottom.plot(t, np.cumsum(values) * dt, color=colour, lw=2.5, label=name, zorder=2)
    # The total is drawn thin and dashed on top of the terms: where one term dominates (the
    # smoothness term's jump from rest, often) its wide line still shows between the dashes.
    total = np.cumsum(rates.error + rates.effort + rates.smoothness) * dt
    bottom.plot(
        t,
        total,
        color="k",
        lw=1.2,
        ls=(0, (4, 3)),
        zorder=3,
        label=f"total V = {total[-1]:.4g}" if len(total) else "total",
    )
    bottom.set_yscale("symlog", linthresh=1e-2)
    bottom.set_xlabel("time (s)")
    bottom.set_ylabel("running cost")
    bottom.legend(fontsize="small")
    bottom.grid(alpha=0.3, which="both")
    return fig


def weight_labels(count: int, task: str | None, task_dim: int) -> list[str]:
    """Names of the quadratic-basis terms behind ``w_0..w_{count-1}`` (e for reach, ξ = [e; x_d] for track)."""
    names = [f"e{i}" for i in range(task_dim)]
    if task is not None and task in TASKS and TASKS[task].moving_reference:
        names += [f"xd{i}" for i in range(task_dim)]
    pairs = [(i, j) for i in range(len(names)) for j in range(i, len(names))]
    if len(pairs) != count:
        return [f"w{k}" for k in range(count)]
    return [f"{names[i]}²" if i == j else f"{names[i]}·{names[j]}" for i, j in pairs]


def plot_critic_weights(log: pd.DataFrame, ax: Any = None) -> Figure:
    """Critic weights Ŵ vs time (one line per basis term)."""
    fig = ax.figure if ax is not None else _figure(7.2, 4.8)
    ax = ax if ax is not None else fig.add_subplot()
    t, w = log["t"].to_numpy(), log_array(log, "w")
    labels = weight_labels(w.shape[1], log.attrs.get("task"), int(log.attrs.get("task_dim", 3)))
    styles = ["-", "--", ":", "-."]
    for k in range(w.shape[1]):
        ax.plot(t, w[:, k], color=_COLOURS[k % 10], ls=styles[(k // 10) % 4], lw=1.2, label=labels[k])
    ax.set_xlabel("time (s)")
    ax.set_ylabel("weight")
    ax.set_title(r"Critic weights $\hat W$")
    ax.legend(ncol=3 if w.shape[1] > 8 else 2, fontsize="x-small")
    ax.grid(alpha=0.3)
    return fig


def plot_model_correction(log: pd.DataFrame) -> Figure:
    """An adaptive controller's model being corrected: the tracking error and the model's prediction error.

    Top: ‖e‖ (mm); bottom: ``model_residual`` ‖x − x̂(θ)‖ (mm), the distance between the measured
    position and the one the controller's current model predicts (0 for an exact model); log scales.
    """
    fig = _figure(7.2, 5.6)
    axes = fig.subplots(2, 1, sharex=True)
    t = log["t"].to_numpy()
    error = np.linalg.norm(log_array(log, "e"), axis=1) * 1e3
    residual = log["model_residual"].to_numpy() * 1e3
    axes[0].semilogy(t, np.maximum(error, 1e-6), color="C0", lw=1.2)
    axes[0].set_ylabel(r"$\|e\|$ (mm)")
    axes[0].set_title("Tracking error")
    axes[1].semilogy(t, np.maximum(residual, 1e-6), color="C3", lw=1.2)
    axes[1].set_ylabel(r"$\|x - \hat x(\theta)\|$ (mm)")
    axes[1].set_title("Prediction error of the controller's arm model (identified on line)")
    axes[1].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    return fig


def plot_optimality(log: pd.DataFrame) -> Figure:
    """How far the critic is from optimal over the run: HJB residual r/eᵀQe, and ‖P̂ − P*‖/‖P*‖ (regulation).

    Both are 0 for the optimal value function (log columns of
    :func:`~snac_gym.rollout.add_critic_diagnostics`).
    """
    with_error = "critic_error" in log.columns
    fig = _figure(7.2, 5.6 if with_error else 3.2)
    axes = fig.subplots(2 if with_error else 1, 1, sharex=True, squeeze=False)[:, 0]
    t = log["t"].to_numpy()
    axes[0].plot(t, log["hjb_ratio"].to_numpy(), color="C0", lw=1.2)
    axes[0].axhline(0.0, color="k", lw=0.8, ls="--", label="optimal critic: 0")
    # r/eᵀQe spans decades on both sides of 0 (large during the first steps, tiny once learnt).
    axes[0].set_yscale("symlog", linthresh=1e-3)
    axes[0].yaxis.set_major_locator(SymmetricalLogLocator(base=10, linthresh=1e-3))
    axes[0].set_ylabel(r"$r\,/\,e^TQe$")
    axes[0].set_title(r"HJB residual $r = \nabla\hat V^T\dot\xi + e^TQe + \hat u^TR\hat u$, relative to $e^TQe$")
    axes[0].legend(fontsize="small")
    axes[0].grid(alpha=0.3)
    if with_error:
        axes[1].plot(t, log["critic_error"].to_numpy(), color="C3", lw=1.2)
        axes[1].set_yscale("log")
        axes[1].set_ylabel(r"$\|\hat P - P^*(J)\|_F / \|P^*\|_F$")
        axes[1].set_title(r"Critic error against the frozen-Jacobian optimum $P^*(J)$")
        axes[1].grid(alpha=0.3, which="both")
    axes[-1].set_xlabel("time (s)")
    return fig


def plot_figure3(log: pd.DataFrame, tolerance: float | None = None) -> Figure:
    """The four panels of the paper's Figure 3 for one run, side by side."""
    fig = _figure(13.0, 9.0)
    grid = fig.add_gridspec(2, 2)
    plot_path(log, ax=fig.add_subplot(grid[0, 0], projection="3d"))
    sub = grid[0, 1].subgridspec(2, 1)
    top = fig.add_subplot(sub[0])
    plot_error(log, axes=(top, fig.add_subplot(sub[1], sharex=top)), tolerance=tolerance)
    plot_joint_velocities(log, ax=fig.add_subplot(grid[1, 0]))
    sub = grid[1, 1].subgridspec(2, 1)
    top = fig.add_subplot(sub[0])
    plot_cost(log, axes=(top, fig.add_subplot(sub[1], sharex=top)))
    return fig


def plot_loop_timing(periods_ms: np.ndarray, dt: float) -> Figure:
    """Control-loop period per step and its histogram (real-robot runs), with the nominal period."""
    fig = _figure(10.0, 3.6)
    left, right = fig.subplots(1, 2)
    periods_ms = np.asarray(periods_ms, dtype=float)
    nominal = dt * 1e3
    left.plot(periods_ms, lw=0.6, color="C0")
    left.axhline(nominal, color="k", ls="--", lw=0.8, label=f"period {nominal:.1f} ms")
    left.set_xlabel("step")
    left.set_ylabel("period (ms)")
    left.legend(fontsize="small")
    left.grid(alpha=0.3)
    right.hist(periods_ms - nominal, bins=60, color="C0")
    right.set_xlabel("jitter: period − nominal (ms)")
    right.set_ylabel("steps")
    right.set_yscale("log")
    right.grid(alpha=0.3)
    return fig


def save_figure(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG to ``path`` (folders created) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_whole(path, lambda partial: fig.savefig(partial, dpi=dpi, format="png"))  # never a truncated PNG
