"""Per-rollout figures: the trajectory cost and what else a reader needs to judge a run.

Two views of the same quantities: :func:`rollout_metrics` (one row per rollout of a batch,
the evaluator's results) and :func:`demo_metrics` (one run's :class:`DemoMetrics`, what
``snac-gym demo`` and ``snac-gym real`` print). Both take the cost from
:func:`snac_gym.control.cost.trajectory_cost`.

The cost is :func:`snac_gym.control.cost.trajectory_cost` (the one function the env reward and the
plots use) under a :class:`snac_gym.control.cost.CostConvention` (``--cost``, ``--udot-start``,
``--q-scale``); by default the paper's Table I cost
``V = Σₖ (eₖᵀQeₖ + uₖᵀRuₖ + u̇ₖᵀRu̇ₖ) Δt`` over the K steps, Q = I₃, R = I₆,
u̇ₖ = (uₖ − uₖ₋₁)/Δt with u₋₁ = 0.

Other columns (one value per rollout):

=====================  ======  ==============================================================
column                 unit    meaning
=====================  ======  ==============================================================
cost                   –       V under the run's convention
cost_error             –       Σ eₖᵀQeₖ Δt (Q = q_scale·I)
cost_effort            –       Σ uₖᵀRuₖ Δt
cost_smoothness        –       Σ u̇ₖᵀRu̇ₖ Δt, u₋₁ per ``udot_start`` (counted in ``cost`` only
                               for ``--cost table1``)
cost_smoothness_start  –       the jump from rest u₀ᵀRu₀/Δt (the first term with u₋₁ = 0)
cost_table1            –       error + effort + smoothness with u₋₁ = 0, whatever the convention
cost_table1_first      –       the same with u₋₁ = u₀ (no jump from rest)
cost_hjb               –       error + effort: the cost of eqs. 6 and 32
first_jump_cost        –       the part of ``cost`` that is the first command's jump from rest:
                               cost_smoothness_start under Table I's cost with u₋₁ = 0, else 0
first_jump_share       –       first_jump_cost / cost (0 where there is no jump)
final_error            m       ‖e_K‖ after the last step
time_to_1mm            s       first tₖ (k = 0..K) with ‖eₖ‖ ≤ 1 mm; NaN if never
settle_time            s       first tₖ from which ‖eⱼ‖ stays within the success tolerance (1
                               mm reach, 5 mm track) up to and including e_K; NaN if ‖e_K‖ is
                               outside it
max_abs_u              rad/s   max over steps and joints of |uₖⱼ| (peak ‖u‖∞)
max_abs_u_step         –       the step k where max_abs_u occurs (first one)
max_norm_u             rad/s   max over steps of ‖uₖ‖₂
peak_limit_fraction    –       max over steps and joints of |uₖⱼ|/ūⱼ (ū: velocity limits; 1 =
                               at a limit)
peak_step              –       the step k where peak_limit_fraction occurs (first one)
max_abs_udot           rad/s²  max over steps and joints of |u̇ₖⱼ| (u₋₁ = 0 included)
steps_at_limit         –       steps with some |uₖⱼ| at its velocity limit
mean_error_2nd_half    m       mean ‖eₖ‖ over k = ⌊K/2⌋..K−1
median_error_2nd_half  m       median ‖eₖ‖ over the same steps
success                –       reach: final_error ≤ 1 mm; track: mean_error_2nd_half ≤ 5 mm;
                               and, where the position limits are given, joint_limit_margin ≥ 0
                               (no joint driven beyond a limit on the way)
hjb_residual_median    –       critic-based controllers: median over the sampled steps of the
                               critic's HJB residual r = ∇V̂ᵀξ̇ + eᵀQe + ûᵀRû; NaN for the others
hjb_ratio_median       –       critic-based controllers: median over the sampled steps of the
                               critic's HJB residual r/eᵀQe (:mod:`snac_gym.control.optimality`; 0 for
                               the optimal critic); NaN for the others
critic_error_final     –       regulation critics: ``‖P̂ − P*(J)‖_F/‖P*‖_F`` at the last step; NaN
                               otherwise
diverged               –       controllers that watch themselves (``snac-adaptive``): the
                               episode crossed one of its divergence bounds (and fell back to a
                               safe command); empty for the others
diverged_time          s       when it was flagged; NaN if never (or not watched)
joint_limit_margin     rad     closest approach to a joint position limit, min over k = 0..K
                               and joints of min(θₖⱼ − θ⁻ⱼ, θ⁺ⱼ − θₖⱼ); negative: a limit was
                               crossed (θ⁻, θ⁺ from the URDF); NaN when no limits are given
=====================  ======  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.control.cost import CostConvention, CostTerms, cost_rates, trajectory_cost
from snac_gym.kernels.metrics import command_extremes, reverse_sum_extremes
from snac_gym.model.joint_limits import joint_limit_margins, joint_limit_margins_of_extremes
from snac_gym.rollout.batch import Rollouts
from snac_gym.rollout.log import log_array
from snac_gym.tasks import get_task

#: Threshold of ``time_to_1mm``, m.
ARRIVAL_TOLERANCE = 1e-3
#: A command counts as at its limit within this relative distance.
LIMIT_RELATIVE_TOLERANCE = 1e-9

METRIC_COLUMNS = (
    "cost",
    "cost_error",
    "cost_effort",
    "cost_smoothness",
    "cost_smoothness_start",
    "cost_table1",
    "cost_table1_first",
    "cost_hjb",
    "first_jump_cost",
    "first_jump_share",
    "final_error",
    "time_to_1mm",
    "settle_time",
    "max_abs_u",
    "max_abs_u_step",
    "max_norm_u",
    "peak_limit_fraction",
    "peak_step",
    "max_abs_udot",
    "steps_at_limit",
    "mean_error_2nd_half",
    "median_error_2nd_half",
    "success",
    "hjb_residual_median",
    "hjb_ratio_median",
    "critic_error_final",
    "diverged",
    "diverged_time",
    "joint_limit_margin",
)


#: Columns that are finite and non-negative in every row (costs, errors, command peaks, counts).
_NON_NEGATIVE = (
    "cost",
    "cost_error",
    "cost_effort",
    "cost_smoothness",
    "cost_smoothness_start",
    "cost_table1",
    "cost_table1_first",
    "cost_hjb",
    "first_jump_cost",
    "first_jump_share",
    "final_error",
    "max_abs_u",
    "max_abs_u_step",
    "max_norm_u",
    "peak_limit_fraction",
    "peak_step",
    "max_abs_udot",
    "steps_at_limit",
    "mean_error_2nd_half",
    "median_error_2nd_half",
)


def check_metric_row(row: Any, task: Any) -> None:
    """Check one row of :func:`rollout_metrics` (a mapping; a row read back from a cache or a file) as its own
    arithmetic fixes it: every column there, costs, errors and peaks finite and ≥ 0, the relations between the
    cost columns that :func:`rollout_metrics` computes (``cost_table1_first`` = ``cost_table1`` −
    ``cost_smoothness_start``; ``first_jump_share`` = ``first_jump_cost``/``cost``), and ``success`` as ``task``'s
    rule gives it from the row's errors and joint margin. An edited cost, a flipped success flag or a row scaled
    as a whole fails one of them.

    Raises:
        ValueError: Naming the first column that does not hold.
    """
    missing = [name for name in METRIC_COLUMNS if name not in row]
    if missing:
        raise ValueError(f"columns missing: {', '.join(missing)}")
    for name in _NON_NEGATIVE:
        value = row[name]
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{name} = {value!r} is not a number")
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} = {value!r} is not finite and non-negative")
    if row["cost_table1_first"] != row["cost_table1"] - row["cost_smoothness_start"]:
        raise ValueError("cost_table1_first is not cost_table1 − cost_smoothness_start")
    share = row["first_jump_cost"] / row["cost"] if row["first_jump_cost"] > 0 else 0.0
    if row["first_jump_share"] != share:
        raise ValueError("first_jump_share is not first_jump_cost / cost")
    success = row["success"]
    if not isinstance(success, (bool, np.bool_)):
        raise ValueError(f"success = {success!r} is not a flag")
    measures = {"final_error": row["final_error"], "mean_error_2nd_half": row["mean_error_2nd_half"]}
    margin = row["joint_limit_margin"]
    expected = bool(get_task(task).success(measures)) and not (margin is not None and margin < 0.0)
    if bool(success) != expected:
        raise ValueError(f"success = {success!r}, but the row's errors and joint margin give {expected}")


def rollout_metrics(
    rollouts: Rollouts,
    task: str,
    velocity_limits: np.ndarray,
    convention: CostConvention | None = None,
    position_limits: tuple[np.ndarray, np.ndarray] | None = None,
) -> pd.DataFrame:
    """One row of :data:`METRIC_COLUMNS` per rollout of ``rollouts``, the cost under ``convention``
    (default: the paper's Table I cost, Q = I₃, R = I₆, u₋₁ = 0); ``task`` (a name or a
    :class:`~snac_gym.tasks.Task`) gives the success rule and the settling tolerance;
    ``position_limits`` ``(θ⁻, θ⁺)`` the ``joint_limit_margin`` column (:func:`limit_margins`)."""
    spec = get_task(task)
    convention = convention if convention is not None else CostConvention()
    dt = rollouts.dt
    commands, errors = rollouts.commands, rollouts.errors
    at_rest = trajectory_cost(errors, commands, dt, Q=convention.error_weight(errors.shape[-1]))  # u₋₁ = 0
    start_jump = cost_rates(errors[:, :1], commands[:, :1], dt).smoothness[:, 0] * dt
    smoothness = at_rest.smoothness if convention.udot_start == "rest" else at_rest.smoothness - start_jump
    terms = CostTerms(at_rest.error, at_rest.effort, smoothness)
    cost = convention.total(terms)
    first_jump = convention.first_jump_weight * start_jump
    # where there is no jump V itself may be 0 (a controller that never moves): the share is 0, not NaN
    first_jump_share = np.divide(first_jump, cost, out=np.zeros_like(cost), where=first_jump > 0)
    error_norms = _vector_norms(errors)  # (B, K)
    final_error = np.linalg.norm(rollouts.final_errors, axis=-1)
    all_norms = np.concatenate([error_norms, final_error[:, None]], axis=1)  # k = 0..K
    arrived = all_norms <= ARRIVAL_TOLERANCE
    first = np.argmax(arrived, axis=1)
    time_to_1mm = np.where(arrived.any(axis=1), first * dt, np.nan)
    outside = all_norms > spec.success_tolerance
    last_outside = all_norms.shape[1] - 1 - np.argmax(outside[:, ::-1], axis=1)
    settle_time = np.where(outside.any(axis=1), (last_outside + 1) * dt, 0.0)
    settle_time[outside[:, -1]] = np.nan
    limits = np.asarray(velocity_limits, dtype=float)
    extremes = command_extremes(
        np.ascontiguousarray(commands, dtype=float), limits, limits * (1.0 - LIMIT_RELATIVE_TOLERANCE), dt
    )
    peak_fraction, peak_step, max_abs_u, max_abs_u_step, max_abs_udot, steps_at_limit = extremes
    second_half_norms = error_norms[:, rollouts.steps // 2 :]
    second_half = second_half_norms.mean(axis=1)
    diagnostics = rollouts.critic_diagnostics or {}
    nan = np.full(len(commands), np.nan)
    success = spec.success({"final_error": final_error, "mean_error_2nd_half": second_half})
    margins = nan if position_limits is None else limit_margins(rollouts, *position_limits)
    if position_limits is not None:  # an arm driven beyond a joint's limit has not done the task
        success = success & (margins >= 0.0)
    return pd.DataFrame(
        {
            "cost": cost,
            "cost_error": terms.error,
            "cost_effort": terms.effort,
            "cost_smoothness": terms.smoothness,
            "cost_smoothness_start": start_jump,
            "cost_table1": at_rest.total,
            "cost_table1_first": at_rest.total - start_jump,
            "cost_hjb": at_rest.error + at_rest.effort,
            "first_jump_cost": first_jump,
            "first_jump_share": first_jump_share,
            "final_error": final_error,
            "time_to_1mm": time_to_1mm,
            "settle_time": settle_time,
            "max_abs_u": max_abs_u,
            "max_abs_u_step": max_abs_u_step,
            "max_norm_u": _vector_norms(commands).max(axis=1),
            "peak_limit_fraction": peak_fraction,
            "peak_step": peak_step,
            "max_abs_udot": max_abs_udot,
            "steps_at_limit": steps_at_limit,
            "mean_error_2nd_half": second_half,
            "median_error_2nd_half": np.median(second_half_norms, axis=1),
            "success": success,
            "hjb_residual_median": diagnostics.get("hjb_residual_median", nan),
            "hjb_ratio_median": diagnostics.get("hjb_ratio_median", nan),
            "critic_error_final": diagnostics.get("critic_error_final", nan),
            "diverged": _diverged_column(rollouts.flags, len(commands)),
            "diverged_time": nan
            if not rollouts.flags
            else np.where(rollouts.flags["diverged"], rollouts.flags["diverged_step"] * dt, np.nan),
            "joint_limit_margin": margins,
        }
    )


def _vector_norms(vectors: np.ndarray) -> np.ndarray:
    """‖v‖₂ of each vector along the last axis of ``vectors`` (a rollout log's ``(B, K, d)``): ``np.linalg.norm(vectors,
    axis=-1)`` bit for bit.

    NumPy adds a last axis shorter than 8 in index order, element by element, which for the logs' d = 3, 6 or 7 took 2
    to 3 times as long as adding the d columns of the whole log in the same order, as here. From 8 on its pairwise sum
    adds in another order, so its own norm is taken there, as for integers and complex numbers.
    """
    vectors = np.asarray(vectors)
    width = vectors.shape[-1]
    if width == 0 or width >= 8 or not np.issubdtype(vectors.dtype, np.floating):
        return np.asarray(np.linalg.norm(vectors, axis=-1))
    squares = vectors[..., 0] * vectors[..., 0]
    for j in range(1, width):
        squares += vectors[..., j] * vectors[..., j]
    return np.sqrt(squares, out=squares) if isinstance(squares, np.ndarray) else np.sqrt(squares)


def _diverged_column(flags: dict[str, np.ndarray] | None, count: int) -> np.ndarray:
    """The ``diverged`` column: True/False for a controller that watches itself, None (missing) for the others.

    Plain Python objects, not pandas' nullable boolean: rows rebuilt from records (the reference cache, a resumed
    run's parts) give the same column, and CSV and Parquet keep True, False and the gap.
    """
    column = np.empty(count, dtype=object)
    column[:] = None if not flags else [bool(flag) for flag in flags["diverged"]]
    return column


def limit_margins(rollouts: Rollouts, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``joint_limit_margin`` of each rollout over θ₀..θ_K, rad.

    Where the rollouts do not keep θₖ (the evaluator's kinematic engine, ``keep_states=False``)
    they are rebuilt from the exact model θₖ₊₁ = θₖ + uₖΔt (eq. 3) backwards from θ_K, exact to
    rounding; this function is therefore only for rollouts of that model or with θₖ kept.
    """
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if rollouts.q is not None:
        q = np.concatenate([rollouts.q, rollouts.final_q[:, None]], axis=1)
        return joint_limit_margins(q, lower, upper)
    # θₖ = θ_K − Σ_{j≥k} uⱼΔt. Only each joint's extremes over k matter, and rounding is monotone:
    # min_k θₖ = θ_K − max_k(Σ_{j≥k} uⱼ)·Δt exactly, so θₖ itself is never formed (θ_K: the sum 0).
    largest, smallest = reverse_sum_extremes(np.ascontiguousarray(rollouts.commands, dtype=float))
    final = rollouts.final_q
    largest = np.maximum(largest, 0.0) * rollouts.dt
    smallest = np.minimum(smallest, 0.0) * rollouts.dt
    return joint_limit_margins_of_extremes(final - largest, final - smallest, lower, upper)


@dataclass
class DemoMetrics:
    """Figures of merit of one closed-loop run (all from its trajectory log).

    Attributes:
        final_error: ‖e‖ after the last step, m.
        time_to_1mm: First time ‖e‖ ≤ 1 mm, s (``None`` if never).
        settling_time: Time after which ‖e‖ stays ≤ ``tolerance`` to the end, s (``None``
            if it ends above).
        tolerance: The settling threshold, m (1 mm reach, 5 mm track).
        max_error_after_settling: Largest ‖e‖ from ``settling_time`` on, m.
        descent_fraction: Fraction of steps with eₖᵀ(eₖ₊₁ − eₖ) ≤ 0, i.e. eᵀė ≤ 0 with ė
            the finite difference over the step (the error norm did not grow).
        descent_fraction_above_tolerance: The same over the steps that start with
            ‖e‖ > ``tolerance`` (the transient; once at the noise floor the sign is random).
        clipped_steps: Steps whose command sits on a velocity limit (|u_j| = limit for some
            joint: the policy or the env clipped it).
        clip_fraction: ``clipped_steps`` / steps.
        max_speed_ratio: Largest |u_j| / limit_j over the run (≤ 1: inside the limits).
        cost_error, cost_effort, cost_smoothness, cost_total: The trajectory cost
            ``V = Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt`` (Q = I, R = I) and its terms.
        steps: Control steps run.
        hjb_ratio_median: Median of the critic's HJB residual r / eᵀQe over the run (critic
            policies only, else ``None``; 0 for the optimal value function).
        critic_error_final: ``‖P̂ − P*(J)‖_F / ‖P*‖_F`` at the last step (regulation critics only).
    """

    final_error: float
    time_to_1mm: float | None
    settling_time: float | None
    tolerance: float
    max_error_after_settling: float | None
    descent_fraction: float
    descent_fraction_above_tolerance: float | None
    clipped_steps: int
    clip_fraction: float
    max_speed_ratio: float
    cost_error: float
    cost_effort: float
    cost_smoothness: float
    cost_total: float
    steps: int
    hjb_ratio_median: float | None = None
    critic_error_final: float | None = None
    mean_error_2nd_half: float = math.nan
    joint_limit_margin: float = math.nan

    def success(self, task: Any) -> bool:
        """Whether the run meets ``task``'s success rule (a name or a :class:`~snac_gym.tasks.Task`) as the
        evaluator scores it: the error rule, and every joint inside its limits (where they were given)."""
        measures = {"final_error": self.final_error, "mean_error_2nd_half": self.mean_error_2nd_half}
        return bool(get_task(task).success(measures)) and not self.joint_limit_margin < 0.0


def demo_metrics(
    log: pd.DataFrame, tolerance: float, position_limits: tuple[np.ndarray, np.ndarray] | None = None
) -> DemoMetrics:
    """Compute :class:`DemoMetrics` from a log of :func:`~snac_gym.rollout.rollout`; ``position_limits``
    ``(θ⁻, θ⁺)`` give its ``joint_limit_margin`` over θ₀..θ_K (NaN without them)."""
    dt = float(log.attrs["dt"])
    errors = log_array(log, "e")
    commands = log_array(log, "u")
    final = np.asarray(log.attrs["final_e"], dtype=float)
    # ‖e‖ at the start of every step, then after the last one.
    norms = np.append(np.linalg.norm(errors, axis=1), np.linalg.norm(final))
    times = np.append(log["t"].to_numpy(), float(log.attrs["final_t"]))
    reached = np.flatnonzero(norms <= 1e-3)
    above = np.flatnonzero(norms > tolerance)
    if not above.size:
        settling_index: int | None = 0
    elif above[-1] + 1 < len(norms):
        settling_index = int(above[-1] + 1)
    else:
        settling_index = None
    following = np.vstack([errors[1:], final[None, :]])
    descent = np.einsum("ij,ij->i", errors, following - errors) <= 0.0
    outside = norms[:-1] > tolerance
    limits = np.asarray(log.attrs["velocity_limits"], dtype=float)
    ratio = np.abs(commands) / limits
    clipped = np.any(ratio >= 1.0 - 1e-12, axis=1)
    cost = trajectory_cost(errors, commands, dt)
    return DemoMetrics(
        final_error=float(norms[-1]),
        time_to_1mm=float(times[reached[0]]) if reached.size else None,
        settling_time=float(times[settling_index]) if settling_index is not None else None,
        tolerance=float(tolerance),
        max_error_after_settling=float(norms[settling_index:].max()) if settling_index is not None else None,
        descent_fraction=float(descent.mean()),
        descent_fraction_above_tolerance=float(descent[outside].mean()) if outside.any() else None,
        clipped_steps=int(clipped.sum()),
        clip_fraction=float(clipped.mean()),
        max_speed_ratio=float(ratio.max()),
        cost_error=float(cost.error),
        cost_effort=float(cost.effort),
        cost_smoothness=float(cost.smoothness),
        cost_total=float(cost.total),
        steps=len(log),
        hjb_ratio_median=float(np.nanmedian(log["hjb_ratio"])) if "hjb_ratio" in log.columns else None,
        critic_error_final=float(log["critic_error"].iloc[-1]) if "critic_error" in log.columns else None,
        mean_error_2nd_half=float(norms[len(errors) // 2 : -1].mean()),  # ‖eₖ‖, k = ⌊K/2⌋..K−1, as the evaluator
        joint_limit_margin=math.nan
        if position_limits is None
        else float(joint_limit_margins(_states(log)[None], *position_limits)[0]),
    )


def _states(log: pd.DataFrame) -> np.ndarray:
    """θ₀..θ_K of a log (θ_K from its metadata, where a cut-short log still has it)."""
    q = log_array(log, "q")
    final = log.attrs.get("final_q")
    return q if final is None else np.vstack([q, np.asarray(final, dtype=float)])
