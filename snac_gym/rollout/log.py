"""The per-step trajectory log of one episode: its columns, critic diagnostics, and its files.

:func:`~snac_gym.rollout.episode.rollout` and :meth:`~snac_gym.rollout.batch.Rollouts.log` produce
it; :func:`write_log` and :func:`read_log` store it as Parquet (and CSV on request) with its
metadata.

Log format: row k holds the state at the **start** of control step k and the command
``u_k`` held over that step. Columns (m joints, task dimension n, l critic weights):

==================  =======  ============================================================
column              unit     meaning
==================  =======  ============================================================
``t``               s        time at the start of step k
``q_0..q_{m-1}``    rad      measured joint positions θₖ
``u_0..u_{m-1}``    rad/s    command applied over step k (after the env's clipping)
``x_0..x_{n-1}``    m        end-effector position f(θₖ), base frame
``x_d_0..``         m        desired position x_d(tₖ)
``xdot_d_0..``      m/s      desired velocity ẋ_d(tₖ)
``e_0..e_{n-1}``    m        error eₖ = xₖ − x_d(tₖ)
``w_0..w_{l-1}``    –        critic weights at the start of step k (before step k's update);
                             only for policies whose ``internals`` hold ``critic_weights``
``hjb_residual``    m²       HJB residual r of the critic at step k (demo and real logs of
                             critic policies, :func:`add_critic_diagnostics`)
``hjb_ratio``       –        r / eₖᵀQeₖ
``critic_error``    –        ‖P̂ − P*(Jₖ)‖_F / ‖P*‖_F (regulation)
NAME                –        each scalar internal a policy names in ``logged_internals``
                             (``snac-adaptive``: ``model_residual``, m, ‖xₖ − x̂(θₖ)‖ of its
                             model before step k's update), after step k's ``act``
==================  =======  ============================================================

``DataFrame.attrs`` (kept by the Parquet file) holds ``dt``, ``task``, ``n_joints``,
``task_dim``, ``seed``, ``options``, ``reference``, ``velocity_limits``, ``policy`` and the
state after the last step: ``final_t``, ``final_q``, ``final_x``, ``final_e``, plus
``terminated``/``truncated``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.common.outputs import write_text_whole, write_whole


def vector_columns(prefix: str, size: int) -> list[str]:
    """Column names ``prefix_0 .. prefix_{size-1}``."""
    return [f"{prefix}_{i}" for i in range(size)]


def log_columns(n_joints: int, task_dim: int, n_weights: int = 0) -> list[str]:
    """The log's columns, in order, for a robot with ``n_joints`` and ``task_dim`` (and l weights)."""
    columns = ["t"] + vector_columns("q", n_joints) + vector_columns("u", n_joints)
    for prefix in ("x", "x_d", "xdot_d", "e"):
        columns += vector_columns(prefix, task_dim)
    return columns + vector_columns("w", n_weights)


def log_array(log: pd.DataFrame, prefix: str) -> np.ndarray:
    """The ``(K, d)`` array of the columns ``prefix_0, prefix_1, …`` of a log (``x`` never matches ``x_d``)."""
    names: list[str] = []
    while f"{prefix}_{len(names)}" in log.columns:
        names.append(f"{prefix}_{len(names)}")
    if not names:
        raise KeyError(f"the log has no columns {prefix}_0, {prefix}_1, ...")
    return log[names].to_numpy()


def jsonable(value: Any) -> Any:
    """Convert arrays/tuples/numpy scalars in nested options to plain JSON types."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "to_dict"):
        return jsonable(value.to_dict())
    return value


def add_critic_diagnostics(log: pd.DataFrame, policy: Any) -> pd.DataFrame:
    """Append the optimality diagnostics of a critic-based policy to its log, row by row.

    For a policy with ``critic_diagnostics`` (SNAC and its variants) and a log with critic
    weights, adds ``hjb_residual`` (r = ∇V̂ᵀξ̇ + eᵀQe + ûᵀRû), ``hjb_ratio`` (r / eᵀQe) and, for
    regulation, ``critic_error`` (``‖P̂ − P*(J)‖_F / ‖P*‖_F``), each from the weights that gave the
    row's command. Other logs are returned unchanged.
    """
    diagnose = getattr(policy, "critic_diagnostics", None)
    if diagnose is None or "w_0" not in log.columns or not len(log):
        return log
    reference = log.attrs.get("reference") or {}
    centre = reference.get("centre", reference.get("target"))
    task_dim = int(log.attrs["task_dim"])
    out = diagnose(
        log_array(log, "q"),
        log_array(log, "e"),
        log_array(log, "x_d"),
        log_array(log, "xdot_d"),
        np.zeros(task_dim) if centre is None else np.asarray(centre, dtype=float),
        log_array(log, "w"),
    )
    attrs = log.attrs
    log = log.assign(**out)
    log.attrs = attrs
    return log


def write_log(log: pd.DataFrame, path: str | Path, csv: bool = False) -> list[Path]:
    """Write ``log`` to ``path`` as Parquet (``attrs`` kept), plus a CSV beside it on request.

    The CSV (same stem, ``.csv``) carries the columns only; its metadata goes to a
    ``.json`` file of the same stem.

    Returns:
        The paths written.
    """
    path = Path(path).with_suffix(".parquet")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_whole(path, lambda partial: log.to_parquet(partial, index=False))
    written = [path]
    if csv:
        csv_path = path.with_suffix(".csv")
        write_whole(csv_path, lambda partial: log.to_csv(partial, index=False, float_format="%.17g"))
        meta_path = path.with_suffix(".json")
        write_text_whole(meta_path, json.dumps(log.attrs, indent=2, default=jsonable))
        written += [csv_path, meta_path]
    return written


def read_log(path: str | Path) -> pd.DataFrame:
    """Read a log written by :func:`write_log` (Parquet, ``attrs`` included)."""
    return pd.read_parquet(path)
