"""Closed-loop rollouts of a policy in a snac-gym env, logged one row per control step.

:func:`rollout` drives any env that exposes the snac-gym observation layout (the PyBullet
envs, the evaluator's kinematic backend, the real-robot env) with any
:class:`~snac_gym.policies.base.Policy`, and returns the trajectory log as a
:class:`pandas.DataFrame`. :func:`write_log` and :func:`read_log` store it as Parquet
(and CSV on request) with its metadata.

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
    names = []
    while f"{prefix}_{len(names)}" in log.columns:
        names.append(f"{prefix}_{len(names)}")
    if not names:
        raise KeyError(f"the log has no columns {prefix}_0, {prefix}_1, ...")
    return log[names].to_numpy()


def _jsonable(value: Any) -> Any:
    """Convert arrays/tuples/numpy scalars in nested options to plain JSON types."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "to_dict"):
        return _jsonable(value.to_dict())
    return value


def rollout(
    env: Any,
    policy: Any,
    options: Mapping[str, Any] | None = None,
    seed: int | None = None,
    steps: int | None = None,
) -> pd.DataFrame:
    """Run ``policy`` in closed loop on ``env`` for one episode and log every control step.

    The env is reset with ``seed`` and ``options``; the policy with ``seed``. The loop ends
    after ``steps`` control steps, or earlier when the env terminates or truncates (so build
    the env with ``max_steps >= steps`` to run longer than its default episode).

    Args:
        env: A snac-gym env (wrapped or not): its unwrapped form has ``obs_layout`` and ``dt``;
            ``info["command"]`` from ``step`` (when present) is logged as the applied command,
            otherwise the policy's output clipped to ``velocity_limits``.
        policy: Any :class:`~snac_gym.policies.base.Policy`.
        options: The env's ``reset`` options (``q0``, ``target`` or ``ellipse``).
        seed: Seed of both resets; the same seed (and options) gives a bit-identical log.
        steps: Most control steps to run (default: until the episode ends).

    Returns:
        The trajectory log (see the module docstring for columns and ``attrs``).

    Raises:
        BaseException: Whatever the env or the policy raises mid-episode (Ctrl-C included)
            propagates unchanged, carrying the rows logged so far as its attribute
            ``rollout_log`` (``attrs["interrupted"]`` names the exception), so that a caller can
            save them (:func:`partial_log`).
    """
    base = getattr(env, "unwrapped", env)
    layout = base.obs_layout
    limits = np.asarray(getattr(base, "velocity_limits", np.full(layout.n_joints, np.inf)), dtype=float)
    horizon = int(steps) if steps is not None else int(getattr(base, "max_steps", 0))
    if horizon < 1:
        raise ValueError("steps must be given (and positive) for an env without max_steps")

    obs, _ = env.reset(seed=seed, options=None if options is None else dict(options))
    policy.reset(seed=seed)
    record = _Record(base, layout, horizon, "critic_weights" in getattr(policy, "internals", {}))
    terminated = truncated = False
    try:
        while record.count < horizon:
            record.state(obs, policy)
            action = policy.act(obs)
            obs, _, terminated, truncated, info = env.step(action)
            applied = info.get("command") if isinstance(info, Mapping) else None
            record.command(applied if applied is not None else np.clip(action, -limits, limits))
            if terminated or truncated:
                break
    except BaseException as exc:
        exc.rollout_log = record.log(policy, obs, options, seed, limits, terminated, truncated)  # type: ignore[attr-defined]
        exc.rollout_log.attrs["interrupted"] = type(exc).__name__
        raise
    return record.log(policy, obs, options, seed, limits, terminated, truncated)


def partial_log(exc: BaseException) -> pd.DataFrame | None:
    """The rows :func:`rollout` logged before ``exc`` interrupted it (``None`` if it did not come from one)."""
    return getattr(exc, "rollout_log", None)


class _Record:
    """The rows of one rollout as they come; a row counts once its command was applied."""

    def __init__(self, base: Any, layout: Any, horizon: int, with_weights: bool) -> None:
        self.base, self.layout = base, layout
        self.times = np.empty(horizon)
        self.observations = np.empty((horizon, layout.size))
        self.commands = np.empty((horizon, layout.n_joints))
        self.weights: list[np.ndarray] | None = [] if with_weights else None
        self.count = 0

    def state(self, obs: np.ndarray, policy: Any) -> None:
        self.times[self.count] = getattr(self.base, "time", self.count * float(self.base.dt))
        self.observations[self.count] = obs
        if self.weights is not None:
            del self.weights[self.count:]  # a row whose command never came
            self.weights.append(np.array(policy.internals["critic_weights"], dtype=float))

    def command(self, applied: np.ndarray) -> None:
        self.commands[self.count] = applied
        self.count += 1

    def log(
        self, policy: Any, obs: np.ndarray, options: Mapping[str, Any] | None, seed: int | None, limits: np.ndarray,
        terminated: bool, truncated: bool,
    ) -> pd.DataFrame:
        layout, base, count, s = self.layout, self.base, self.count, self.layout.slices
        m, n, dt = layout.n_joints, layout.task_dim, float(base.dt)
        obs_rows = self.observations[:count]
        blocks = [self.times[:count, None], obs_rows[:, s["q"]], self.commands[:count]]
        blocks += [obs_rows[:, s[name]] for name in ("x", "x_d", "xdot_d", "e")]
        weights = None if self.weights is None else self.weights[:count]
        n_weights = 0
        if weights:
            n_weights = len(weights[0])
            blocks.append(np.stack(weights))
        log = pd.DataFrame(np.hstack(blocks), columns=log_columns(m, n, n_weights))
        last = layout.unpack(obs)
        reference = getattr(base, "reference", None)
        log.attrs = {
            "dt": dt,
            "task": getattr(base, "task_name", None),
            "n_joints": m,
            "task_dim": n,
            "seed": seed,
            "options": _jsonable(options) if options is not None else None,
            "reference": _jsonable(reference.to_dict()) if reference is not None else None,
            "velocity_limits": limits.tolist(),
            "policy": type(policy).__name__,
            "final_t": float(getattr(base, "time", count * dt)),
            "final_q": last.q.tolist(),
            "final_x": last.x.tolist(),
            "final_e": last.e.tolist(),
            "terminated": bool(terminated),
            "truncated": bool(truncated),
        }
        return log


def add_critic_diagnostics(log: pd.DataFrame, policy: Any) -> pd.DataFrame:
    """Append the optimality diagnostics of a critic-based policy to its log, row by row.

    For a policy with ``critic_diagnostics`` (SNAC and its variants) and a log with critic
    weights, adds ``hjb_residual`` (r = ∇V̂ᵀξ̇ + eᵀQe + ûᵀRû), ``hjb_ratio`` (r / eᵀQe) and, for
    regulation, ``critic_error`` (‖P̂ − P*(J)‖_F / ‖P*‖_F), each from the weights that gave the
    row's command. Other logs are returned unchanged.
    """
    diagnose = getattr(policy, "critic_diagnostics", None)
    if diagnose is None or "w_0" not in log.columns or not len(log):
        return log
    reference = log.attrs.get("reference") or {}
    centre = reference.get("centre", reference.get("target"))
    task_dim = int(log.attrs["task_dim"])
    out = diagnose(
        log_array(log, "q"), log_array(log, "e"), log_array(log, "x_d"), log_array(log, "xdot_d"),
        np.zeros(task_dim) if centre is None else np.asarray(centre, dtype=float), log_array(log, "w"),
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
    log.to_parquet(path, index=False)
    written = [path]
    if csv:
        csv_path = path.with_suffix(".csv")
        log.to_csv(csv_path, index=False, float_format="%.17g")
        meta_path = path.with_suffix(".json")
        meta_path.write_text(json.dumps(log.attrs, indent=2, default=_jsonable))
        written += [csv_path, meta_path]
    return written


def read_log(path: str | Path) -> pd.DataFrame:
    """Read a log written by :func:`write_log` (Parquet, ``attrs`` included)."""
    return pd.read_parquet(path)
