"""A batch of rollouts as arrays, and its conversion to the per-step log.

Both engines return a :class:`Rollouts` (:func:`~snac_gym.rollout.kinematic.simulate_kinematic`
and :func:`~snac_gym.rollout.episode.simulate_env`): row ``k`` of every per-step array is
the state at the start of control step ``k`` and the command ``uₖ`` held over that step (the
convention of the trajectory log and of the trajectory cost); ``final_*`` is the state after
the last step.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import pandas as pd

from snac_gym.common.errors import RolloutError  # noqa: F401  (its name here before snac_gym.common.errors)
from snac_gym.rollout.log import log_array, log_columns


@dataclass
class Rollouts:
    """B rollouts of K control steps each.

    Attributes:
        dt: Control period, s.
        times: ``(K,)`` time at the start of each step, s.
        q: ``(B, K, m)`` joint positions θₖ, rad (``None`` if not kept: see
            :func:`~snac_gym.rollout.kinematic.simulate_kinematic`).
        commands: ``(B, K, m)`` commands uₖ applied over step k (after clipping), rad/s.
        x: ``(B, K, n)`` end-effector positions f(θₖ), m (``None`` if not kept).
        x_d: ``(B, K, n)`` desired positions x_d(tₖ), m.
        xdot_d: ``(B, K, n)`` desired velocities ẋ_d(tₖ), m/s.
        errors: ``(B, K, n)`` errors eₖ = xₖ − x_d(tₖ), m.
        final_q: ``(B, m)`` θ_K after the last step.
        final_x: ``(B, n)`` f(θ_K).
        final_errors: ``(B, n)`` e_K.
        critic_diagnostics: For critic-based controllers, ``hjb_ratio_median`` and
            ``critic_error_final`` ``(B,)`` (:func:`summarise_critic_diagnostics`); ``None`` otherwise.
        flags: For controllers that watch themselves, their per-rollout flags (``diverged`` ``(B,)``
            bool and ``diverged_step`` ``(B,)``, −1 where never); ``None`` otherwise.
    """

    dt: float
    times: np.ndarray
    q: np.ndarray | None
    commands: np.ndarray
    x: np.ndarray | None
    x_d: np.ndarray
    xdot_d: np.ndarray
    errors: np.ndarray
    final_q: np.ndarray
    final_x: np.ndarray
    final_errors: np.ndarray
    critic_diagnostics: dict[str, np.ndarray] | None = None
    flags: dict[str, np.ndarray] | None = None

    @property
    def count(self) -> int:
        """Number of rollouts B."""
        return int(self.commands.shape[0])

    @property
    def steps(self) -> int:
        """Number of control steps K."""
        return int(self.commands.shape[1])

    def log(self, i: int, attrs: dict[str, Any] | None = None) -> pd.DataFrame:
        """Rollout ``i`` as the demo's per-step log (columns of :func:`snac_gym.rollout.log.log_columns`).

        ``attrs`` is merged into the log's metadata after ``dt``, ``final_t``, ``final_q``,
        ``final_x`` and ``final_e``.
        """
        if self.q is None or self.x is None:
            raise ValueError("these rollouts were run without their states (keep_states=False): no per-step log")
        m, n = self.q.shape[-1], self.x.shape[-1]
        blocks = [
            self.times[:, None],
            self.q[i],
            self.commands[i],
            self.x[i],
            self.x_d[i],
            self.xdot_d[i],
            self.errors[i],
        ]
        log = pd.DataFrame(np.hstack(blocks), columns=log_columns(m, n))
        log.attrs = {
            "dt": self.dt,
            "n_joints": m,
            "task_dim": n,
            "final_t": float(self.steps * self.dt),
            "final_q": self.final_q[i].tolist(),
            "final_x": self.final_x[i].tolist(),
            "final_e": self.final_errors[i].tolist(),
            **(attrs or {}),
        }
        return log


def rollouts_from_logs(logs: list[pd.DataFrame]) -> Rollouts:
    """Stack per-step logs of equal length (e.g. from :func:`snac_gym.rollout.episode.rollout`) into
    :class:`Rollouts`."""
    if not logs:
        raise ValueError("no logs to stack")
    lengths = {len(log) for log in logs}
    if len(lengths) != 1:
        raise ValueError(f"logs must have the same number of steps, got lengths {sorted(lengths)}")

    def stack(prefix: str) -> np.ndarray:
        return np.stack([log_array(log, prefix) for log in logs])

    diagnostics = None
    if all("hjb_ratio" in log.columns for log in logs):
        diagnostics = summarise_critic_diagnostics(
            np.stack([log["hjb_residual"].to_numpy() for log in logs]),
            np.stack([log["hjb_ratio"].to_numpy() for log in logs]),
            np.stack([log["critic_error"].to_numpy() for log in logs]) if "critic_error" in logs[0] else None,
        )
    flags = None
    if all("diverged" in log.columns for log in logs):
        flagged = np.stack([log["diverged"].to_numpy() > 0 for log in logs])
        flags = {
            "diverged": cast(np.ndarray, flagged.any(axis=1)),  # along an axis: an array
            "diverged_step": np.where(flagged.any(axis=1), flagged.argmax(axis=1), -1),
        }
    return Rollouts(
        dt=float(logs[0].attrs["dt"]),
        times=logs[0]["t"].to_numpy(),
        q=stack("q"),
        commands=stack("u"),
        x=stack("x"),
        x_d=stack("x_d"),
        xdot_d=stack("xdot_d"),
        errors=stack("e"),
        final_q=np.array([log.attrs["final_q"] for log in logs], dtype=float),
        final_x=np.array([log.attrs["final_x"] for log in logs], dtype=float),
        final_errors=np.array([log.attrs["final_e"] for log in logs], dtype=float),
        critic_diagnostics=diagnostics,
        flags=flags,
    )


def summarise_critic_diagnostics(
    hjb_residual: np.ndarray, hjb_ratio: np.ndarray, critic_error: np.ndarray | None
) -> dict[str, np.ndarray]:
    """Per rollout: the medians of r and r/eᵀQe over the (sampled) steps and the last critic error.

    Args:
        hjb_residual: ``(B, S)`` the critic's HJB residual r at S steps.
        hjb_ratio: ``(B, S)`` r/eᵀQe at the same steps (NaN where e = 0).
        critic_error: ``(B, S)`` its critic error at the same steps (regulation), or ``None``.
    """

    def median(values: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN row (e = 0 throughout) stays NaN
            return np.nanmedian(np.where(np.isfinite(values), values, np.nan), axis=1)

    out = {"hjb_residual_median": median(hjb_residual), "hjb_ratio_median": median(hjb_ratio)}
    if critic_error is not None:
        out["critic_error_final"] = critic_error[:, -1]
    return out
