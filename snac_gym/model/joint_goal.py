"""A goal configuration within the joint limits, and the virtual arm that carries it along a moving reference.

The resolved-rate laws (DLS, ``lqr``, SNAC, and PPO's task-relative map) move the end effector the
short way and let the joints follow: on the arm's whole reach that path leaves a joint's range on
about a fifth of the samples (the base past ±2π, the elbow past ±π), and clamping the joints there
stalls instead. Every sample's target is the end effector of some configuration inside the limits,
and the joint box is convex, so a straight joint-space path to such a configuration never leaves it.
This module finds that configuration:

    θ* = argmin ‖θ − θ₀‖²   s.t.  f(θ) = x_d,   θ⁻ + δ ≤ θ ≤ θ⁺ − δ

(‖u‖² is the effort the cost charges, so the nearest goal is the cheapest to travel to), by damped
least-squares IK with a null-space pull towards θ₀, projected onto the box, from θ₀ and from a fixed
set of configurations spread over the box (:func:`goal_starts`): other IK branches and the other way
round a joint. The nearest converged solution wins. Everything is batched over samples.

For a moving reference the goal is the solution for x_d(0), and a *virtual arm* (:class:`GoalArms`)
starting there follows x_d(t) exactly on that branch (θ̇* = J⁺(θ*)(ẋ_d + K(x_d − f(θ*))), kept inside
the box), so a controller can track θ*(t) in joint space and its end effector tracks x_d.

It is a model-based, deterministic computation (no randomness at run time: the starts come from a
fixed seed), used by the ``joint-goal`` controller, the PPO ``goal-relative`` action and the
reference's own starts.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from snac_gym.model.position_kinematics import damped_resolve_rows

#: δ, rad: the distance a goal keeps from every joint limit.
GOAL_MARGIN = 0.05
#: Spread starts besides θ₀ (each another IK branch or winding with some probability).
GOAL_STARTS = 15
#: Seed of the spread starts: fixed, so a sample always gets the same goal.
GOAL_STARTS_SEED = 20261128
#: Position tolerance of a goal, m.
GOAL_TOLERANCE = 1e-9
#: The room (rad from every limit) a goal for a moving reference is preferred to have: an ellipse of up to
#: 0.2 m semi-axes swings the joints by tenths of a radian about the goal.
TRACKING_ROOM = 0.5
#: K of the virtual arm's error feedback, 1/s (K·Δt = 0.08 at 125 Hz).
VIRTUAL_ARM_GAIN = 10.0
_DAMPING = 1e-2  # λ of the IK's damped pseudo-inverse, m
_PULL = 0.2  # the null-space step towards θ₀, a fraction of the remaining distance
_TRUST = 0.5  # largest IK step, rad: keeps an iteration on its branch
_ITERATIONS = 300
_POLISH = 30  # last iterations without the pull: converge onto f(θ) = x_d exactly
#: A row of the IK that moves less than this (max |Δθ|, rad) in an iteration with the pull has converged there and
#: is not iterated again until the polish: its goal ends within 1e-10 rad of the one all the iterations give
#: (Table I's samples), and the IK of the reference's branch search takes a third less time.
_SETTLED = 1e-11
#: The IK's solved rows of each kinematic model, by what a row's solution depends on (θ₀, its start, its target, the
#: box): the reference's `joint-goal` start and its branch search then solve θ₀ and the first spread starts of a
#: sample once, not twice (both draw the spread starts from one seed; a row's iteration depends on that row alone).
#: Emptied when it holds _SOLVED_ROWS rows (a reference job asks for about 12 000).
_SOLVED: weakref.WeakKeyDictionary[Any, dict[bytes, np.ndarray]] = weakref.WeakKeyDictionary()
_SOLVED_ROWS = 50_000


def goal_starts(
    lower: np.ndarray, upper: np.ndarray, count: int = GOAL_STARTS, margin: float = GOAL_MARGIN
) -> np.ndarray:
    """``count`` configurations spread uniformly over the box less ``margin`` (fixed seed), ``(count, m)``."""
    low, high = np.asarray(lower, float) + margin, np.asarray(upper, float) - margin
    if np.any(low >= high):
        raise ValueError(f"joint limits leave no room inside a margin of {margin} rad")
    return np.random.default_rng(GOAL_STARTS_SEED).uniform(low, high, size=(count, len(low)))


def _resolve(jac: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """``Jᵀ(JJᵀ + λ²I)⁻¹ v`` for stacks ``(B, n, m)``, ``(B, n)``, at the IK's λ."""
    return damped_resolve_rows(jac, velocity, _DAMPING)


def nearest_goals(
    kinematics: Any,
    q0: np.ndarray,
    targets: np.ndarray,
    margin: float = GOAL_MARGIN,
    starts: np.ndarray | None = None,
    tol: float = GOAL_TOLERANCE,
    preferred_margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The configuration nearest ``q0`` that reaches each target inside the joint limits (module docs).

    Args:
        kinematics: A position :class:`~snac_gym.model.kinematics.Kinematics` (``forward_and_jacobian_batch``).
        q0: Start configurations ``(B, m)`` (or one ``(m,)``).
        targets: End-effector targets ``(B, 3)`` (or one ``(3,)``), base frame, m.
        margin: δ, rad.
        starts: Spread starts ``(S, m)``; default :func:`goal_starts`.
        tol: Position tolerance, m.
        preferred_margin: Prefer the nearest goal at least this far (rad) from every limit where one was
            found: a goal for a moving reference needs room to move in.

    Returns:
        ``(goals, found)``: ``(B, m)`` configurations and ``(B,)`` flags. Where no start converged,
        ``found`` is False and the goal is the start that came closest.

    Raises:
        ValueError: On a pose kinematics (6-D task) or shapes that do not match.
    """
    if getattr(kinematics, "task_error", None) is not None or kinematics.task_dim != 3:
        raise ValueError("a joint-space goal is defined for the 3-D position tasks only")
    single = np.ndim(q0) == 1
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    targets = np.atleast_2d(np.asarray(targets, dtype=float))
    m = kinematics.n_joints
    if q0.shape[1] != m or targets.shape != (len(q0), 3):
        raise ValueError(f"need q0 (B, {m}) and targets (B, 3), got {q0.shape} and {targets.shape}")
    q, anchor, goal, count, per = _solve(kinematics, q0, targets, margin, starts)
    residual = np.linalg.norm(kinematics.forward_batch(q) - goal, axis=1).reshape(count, per)
    distance = np.sum((q - anchor) ** 2, axis=1).reshape(count, per)
    converged = residual <= tol
    room = np.min(np.minimum(q - kinematics.lower_limits, kinematics.upper_limits - q), axis=1).reshape(count, per)
    roomy = converged & (room >= preferred_margin)
    score = np.where(roomy, distance, np.where(converged, distance + 1e6, np.inf))
    best = np.where(converged.any(axis=1), np.argmin(score, axis=1), np.argmin(residual, axis=1))
    goals = q.reshape(count, per, m)[np.arange(count), best]
    found = converged[np.arange(count), best]
    return (goals[0], found[:1]) if single else (goals, found)


def _solve(
    kinematics: Any, q0: np.ndarray, targets: np.ndarray, margin: float, starts: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The IK of every target from its ``q0`` and from every spread start: ``(q, anchor, goal, count, per)`` with
    ``q``, ``anchor`` (θ₀ of each candidate) and ``goal`` stacked ``(count · per, ·)``, ``per`` = 1 + len(starts).
    Rows this arm's IK has solved before are served from :data:`_SOLVED`, the others iterated (:func:`_iterate`)."""
    m = kinematics.n_joints
    low, high = kinematics.lower_limits + margin, kinematics.upper_limits - margin
    spread = goal_starts(kinematics.lower_limits, kinematics.upper_limits, margin=margin) if starts is None else starts
    count, per = len(q0), 1 + len(spread)
    anchor = np.repeat(q0, per, axis=0)  # θ₀ of every candidate
    goal = np.repeat(targets, per, axis=0)
    q = np.concatenate([q0[:, None, :], np.broadcast_to(spread, (count, len(spread), m))], axis=1).reshape(-1, m)
    q = np.clip(q, low, high)
    solved = _SOLVED.setdefault(kinematics, {})
    if len(solved) > _SOLVED_ROWS:
        solved.clear()
    keys = [row.tobytes() for row in np.concatenate([anchor, q, goal, np.broadcast_to(low, q.shape)], axis=1)]
    known = np.array([key in solved for key in keys], dtype=bool)
    for i in np.flatnonzero(known):
        q[i] = solved[keys[i]]
    todo = np.flatnonzero(~known)
    if len(todo):
        q[todo] = _iterate(kinematics, q[todo], anchor[todo], goal[todo], low, high)
        solved.update((keys[i], q[i].copy()) for i in todo)
    return q, anchor, goal, count, per


def _iterate(
    kinematics: Any, q: np.ndarray, anchor: np.ndarray, goal: np.ndarray, low: np.ndarray, high: np.ndarray
) -> np.ndarray:
    """The IK's iterations from the rows of ``q``, each towards its ``goal`` with the null-space pull to its
    ``anchor`` (θ₀), inside [``low``, ``high``]; each row's result depends on that row alone."""
    q = q.copy()
    moving = np.arange(len(q))  # the rows that still move
    for iteration in range(_ITERATIONS):
        pulled = iteration < _ITERATIONS - _POLISH
        if iteration == _ITERATIONS - _POLISH:
            moving = np.arange(len(q))  # the polish moves every row again
        if not len(moving):
            continue
        here = q[moving]
        x, jac = kinematics.forward_and_jacobian_batch(here)
        step = _resolve(jac, goal[moving] - x)
        if pulled:  # (I − J⁺J)·d: the part of d = θ₀ − θ that leaves f(θ) alone
            towards = anchor[moving] - here
            step = step + _PULL * (towards - _resolve(jac, np.einsum("bij,bj->bi", jac, towards)))
        norms = np.linalg.norm(step, axis=1, keepdims=True)
        moved = np.clip(here + step * np.minimum(1.0, _TRUST / np.maximum(norms, 1e-300)), low, high)
        q[moving] = moved
        # A row that moves less than _SETTLED with the pull has converged there (the pull contracts its distance by
        # 1 − _PULL an iteration) and waits for the polish; one the polish leaves where it was stays there (a row's
        # iteration depends on that row alone).
        moving = moving[np.abs(moved - here).max(axis=1) > (_SETTLED if pulled else 0.0)]
    return q


def goals_and_limit_stops(
    kinematics: Any,
    q0: np.ndarray,
    targets: np.ndarray,
    starts: np.ndarray,
    margin: float = GOAL_MARGIN,
    tol: float = GOAL_TOLERANCE,
    separation: float = 0.5,
    stop_residual: float = 0.0,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per sample, every distinct in-limit configuration that reaches its target found from its ``q0`` and from
    ``starts`` (S, m): one per IK branch and winding, each the one of its branch nearest ``q0`` (the null-space
    pull), nearest first, ``(G, m)``; and the distinct IK ends that a joint limit stopped within ``stop_residual`` (m)
    of the target, nearest ``q0`` first: a branch that reaches the target only past a limit, whose nearest in-limit
    configuration presses against it (none with the default 0). Two solutions closer than ``separation`` (max |Δθ|,
    rad) are one.

    Args:
        q0: ``(B, m)`` start configurations; targets: ``(B, 3)``.
    """
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    targets = np.atleast_2d(np.asarray(targets, dtype=float))
    q, anchor, goal, count, per = _solve(kinematics, q0, targets, margin, starts)
    residual = np.linalg.norm(kinematics.forward_batch(q) - goal, axis=1).reshape(count, per)
    converged = residual <= tol
    low, high = kinematics.lower_limits + margin, kinematics.upper_limits - margin
    pressed = ((q <= low) | (q >= high)).any(axis=1).reshape(count, per)  # the IK's clip holds a joint there
    stopped = ~converged & pressed & (residual <= stop_residual)
    distance = np.sum((q - anchor) ** 2, axis=1).reshape(count, per)
    q = q.reshape(count, per, -1)

    def nearest_first(kept: np.ndarray, i: int) -> np.ndarray:
        order = np.argsort(np.where(kept[i], distance[i], np.inf), kind="stable")[: int(kept[i].sum())]
        return distinct_configurations(q[i, order], separation)

    return [nearest_first(converged, i) for i in range(count)], [nearest_first(stopped, i) for i in range(count)]


def distinct_configurations(configurations: np.ndarray, separation: float) -> np.ndarray:
    """``configurations`` ``(N, m)`` without those within ``separation`` (max |Δθ|, rad) of an earlier one kept: one
    per branch, the first of each in the given order, ``(G, m)``."""
    configurations = np.asarray(configurations, dtype=float)
    m = configurations.shape[-1]
    configurations = configurations.reshape(-1, m)
    # Every pair's distance at once: the branch search calls this thousands of times a run on a few dozen rows.
    apart = np.abs(configurations[:, None] - configurations[None]).max(axis=-1, initial=0.0) >= separation
    kept = np.zeros(len(configurations), dtype=bool)
    for i in range(len(configurations)):
        kept[i] = apart[i, kept].all()  # against the earlier ones kept (the later ones are not marked yet)
    return configurations[kept]


class GoalArms:
    """B virtual arms: each starts at its goal configuration and follows its reference exactly, inside the box.

    ``θ*ₖ₊₁ = clip(θ*ₖ + Δt·sat(J⁺(θ*ₖ)(ẋ_d(tₖ) + K(x_d(tₖ) − f(θ*ₖ)))))`` with the damped pseudo-inverse,
    ``sat`` the uniform scaling into the velocity limits and the clip into the box less δ. For a fixed
    target (``moving=False``) the arm stays at its goal and a step computes nothing.

    Args:
        kinematics: The position kinematics.
        velocity_limits: ū, rad/s ``(m,)``.
        dt: Control period, s.
        margin: δ, rad.
        gain: K, 1/s.
        preferred_margin: Of :func:`nearest_goals` (rad).
        moving: Whether the reference moves (tracking).
    """

    def __init__(
        self,
        kinematics: Any,
        velocity_limits: np.ndarray,
        dt: float,
        margin: float = GOAL_MARGIN,
        gain: float = VIRTUAL_ARM_GAIN,
        preferred_margin: float = 0.0,
        moving: bool = True,
    ) -> None:
        self.kinematics = kinematics
        self.velocity_limits = np.asarray(velocity_limits, dtype=float)
        self.dt = float(dt)
        self.margin = float(margin)
        self.gain = float(gain)
        self.preferred_margin = float(preferred_margin)
        self.moving = bool(moving)
        self.low = kinematics.lower_limits + self.margin
        self.high = kinematics.upper_limits - self.margin
        self.q = np.zeros((0, kinematics.n_joints))
        self.found = np.zeros(0, dtype=bool)

    def start(self, q0: np.ndarray, x_d: np.ndarray, rows: np.ndarray | None = None) -> None:
        """Place the arms (all, or ``rows`` of ``count`` allocated ones) at the goals for ``x_d`` ``(B, 3)`` nearest
        ``q0`` ``(B, m)``."""
        goals, found = nearest_goals(self.kinematics, q0, x_d, self.margin, preferred_margin=self.preferred_margin)
        if rows is None:
            self.q, self.found = goals, found
        else:
            self.q[rows], self.found[rows] = goals, found

    def allocate(self, count: int) -> None:
        """Room for ``count`` arms, to be started row by row (:meth:`start` with ``rows``)."""
        self.q = np.zeros((count, self.kinematics.n_joints))
        self.found = np.zeros(count, dtype=bool)

    def step(
        self, x_d: np.ndarray, xdot_d: np.ndarray, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Advance every arm (or ``rows`` of them) one period; returns ``(θ*ₖ, θ̇*ₖ)``, the configuration and the
        velocity it moves with (after the clip into the box: a controller that feeds it forward does not push
        past a limit)."""
        current = self.q if rows is None else self.q[rows]
        if not self.moving:
            return current.copy(), np.zeros_like(current)
        x, jac = self.kinematics.forward_and_jacobian_batch(current)
        velocity = _resolve(jac, xdot_d + self.gain * (x_d - x))
        velocity = velocity / np.maximum(1.0, np.max(np.abs(velocity) / self.velocity_limits, axis=1, keepdims=True))
        moved = np.clip(current + self.dt * velocity, self.low, self.high)
        if rows is None:
            self.q = moved
        else:
            self.q[rows] = moved
        return current, (moved - current) / self.dt


__all__ = [
    "GOAL_MARGIN", "TRACKING_ROOM", "GoalArms", "distinct_configurations", "goal_starts", "goals_and_limit_stops",
    "nearest_goals",
]  # fmt: skip
