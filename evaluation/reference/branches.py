"""The reference's starts on the other IK branches: one per distinct in-limit configuration that reaches the target.

A local solve descends into the basin its start lies in, and on the arm's whole reach the cheapest basin can lie on
another IK branch or the other way round a joint: on a held-out track sample (UR10, workspace, HJB cost) IPOPT's
first long steps from rest flipped the elbow (Δθ₃ = 4.6 rad) and found an optimum 3.4 % below the one every start of
the reference's own descended to, a KKT point that IPOPT started there confirms. So the reference also starts from
each branch, drawn from the sample alone:

* the goals (:func:`~snac_gym.model.joint_goal.goals_and_limit_stops`): every distinct in-limit IK solution of the
  target (reach) or of the ellipse's first point (track) found from θ₀ and from :data:`BRANCH_SPREAD` fixed
  configurations spread over the joint box, each the one of its branch nearest θ₀, and from :data:`LOCAL_STARTS`
  configurations near θ₀ (θ₀ plus fixed offsets of up to :data:`LOCAL_SPREAD` rad per joint), each the one nearest its
  start: with six joints and a 3-D target the solutions form 3-D sets whose distance from θ₀ has several local minima,
  and the nearest can be one that the IK from θ₀ does not descend to (a held-out track sample: 1.91 rad from θ₀ where
  the IK from θ₀ ended 2.53 rad away, the optimum there 17.7 % below every other start's); each goal is then turned by
  whole turns the short way round every joint whose range allows it (:func:`wrapped_towards`): the IK ends the way round
  its start lies, and the other way can be the cheaper basin (a held-out track sample, 0.9 % below every start before;
  on whole-workspace tracks of that seed 3 of 100 references fell by up to 4.4 %, and the search took 30 % less time,
  with fewer distinct goals to screen);
* the IK ends that a joint limit stopped within :data:`LIMIT_STOP_RESIDUAL` of the target (after the goals, so their
  names do not change): a branch that reaches the target only past a limit, as near as the limit lets it come (a
  held-out reach: the optimum, 7.6 % below every other start's and IPOPT's from the goals, has the base against its
  limit 6 mm short of the target; no IK goal lies on that branch, which needs the base 0.5 rad past the limit);
* a start per goal (:func:`branch_commands`): the ``joint-goal`` law towards it, u = sat(θ̇* + K(θ* − θ)), with the
  virtual arm carrying θ* along a moving reference on that branch: a straight joint path, inside the limits;
* :data:`RANDOM_STARTS` starts that go straight to a random configuration of the joint box over the first half of
  the horizon and rest there (:func:`random_configurations`, seeded by the sample itself): a tracking optimum can
  lie on a branch of a later point of the ellipse, which no IK of its first point finds (a held-out track sample:
  17.7 % below the best branch start, reached from 2 of 12 such starts).

Most branches cannot win, and are dropped before any solve:

* where the solve from rest stops short of the target (by more than :data:`REACHED`) with no limit active, the cost
  prefers not to travel (Table I's Q = I): a farther branch, more travel, cannot win, and none is tried; except
  behind a moving reference whose solve from rest passes near a singular arm (:data:`NEAR_SINGULAR`): there
  following is dear on that branch, whatever the lag at the end, and another branch may follow for less;
* a goal within :data:`BRANCH_SEPARATION` of where an optimum already found ends is that optimum's branch;
* a goal so far from θ₀ that the effort of getting there alone, (‖θ* − θ₀‖ − :data:`BRANCH_SEPARATION`)²/T
  (Cauchy–Schwarz: ∫‖u‖² dt ≥ ‖∫u dt‖²/T over the horizon T, R = I), is above the best cost found cannot win
  (no optimum that ends on that branch can).

The same effort test drops a random configuration, but there it is **not a bound**, only a filter that keeps the
search affordable: the solve from a random start can end anywhere, not at its configuration, and on a held-out
track sample (223/19) the start that led IPOPT's way was one it dropped. It is kept because without it the
reference of Table I's main command costs 3.3× as much (8 more screens on nearly every reach sample, measured),
and that sample's optimum is now found from a local IK goal instead.

The rest are screened as the reference's other starts are (on a coarse time grid, stopped once in a known basin,
the cheapest few coarse optima polished: :func:`snac_gym.evaluation.reference.optimum.multi_start_solve`).
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from snac_gym.model.joint_goal import (
    GOAL_MARGIN,
    GoalArms,
    distinct_configurations,
    goal_starts,
    goals_and_limit_stops,
)
from snac_gym.model.kinematics import joint_step
from snac_gym.policies.base import scale_rows_into_limits

#: Spread IK starts besides θ₀ (a fixed seed: a sample always gets the same goals).
BRANCH_SPREAD = 23
#: IK starts near θ₀ besides those: θ₀ plus fixed offsets drawn uniformly from ±LOCAL_SPREAD rad per joint.
LOCAL_STARTS = 8
#: Half-width of the local starts' offsets, rad.
LOCAL_SPREAD = 1.0
#: Seed of the local starts' offsets (fixed: a sample always gets the same goals).
LOCAL_SEED = 20261129
#: Two goals closer than this (max |Δθ|, rad) are one branch; a goal this close to an optimum's end is its branch.
BRANCH_SEPARATION = 0.5
#: K of the start's joint-space law, 1/s (the ``joint-goal`` controller's default).
BRANCH_GAIN = 2.0
#: The end-effector distance (m) from the reference's last point within which the solve from rest has travelled
#: there: the cost pays for travel, and another branch might travel for less.
REACHED = 0.01
#: Where the solve from rest's path comes this near a singular arm (the smallest singular value of the position
#: Jacobian, m/rad), following a moving reference is dear on its branch and another branch may follow it for less,
#: whether or not it kept up at the end: its branches are searched. Three held-out workspace tracks missed a
#: cheaper basin by 4-35 % without it, their paths at 0.06-0.13; Table I's tracks stay above 0.24 (200 samples).
NEAR_SINGULAR = 0.2
#: Every SINGULAR_STRIDE-th point of the path is checked for :data:`NEAR_SINGULAR` (0.2 s at Table I's period).
SINGULAR_STRIDE = 25
#: An IK end that a joint limit stopped within this distance (m) of the target is a start too: the branch past the
#: limit, as near as the limit lets it come (a held-out reach: IPOPT from rest found an optimum 7.6 % below every
#: start's with the base against its limit, 6 mm short of the target; the IK's end there was 5.4 cm short).
LIMIT_STOP_RESIDUAL = 0.1
#: Name prefix of a branch start in ``optimal_winner``.
BRANCH_PREFIX = "branch-"
#: Random in-limit configurations a sample's reference also starts towards.
RANDOM_STARTS = 8
#: Name prefix of a random start in ``optimal_winner``.
RANDOM_PREFIX = "random-"


def random_configurations(kinematics: Any, q0: np.ndarray, first_point: np.ndarray) -> np.ndarray:
    """:data:`RANDOM_STARTS` configurations drawn uniformly from the joint box less the goal margin, ``(S, m)``, from a
    generator seeded by the sample's own θ₀ and first reference point: the same sample always gets the same ones."""
    key = np.ascontiguousarray(np.concatenate([np.asarray(q0, dtype=float), np.asarray(first_point, dtype=float)]))
    rng = np.random.default_rng(int.from_bytes(hashlib.sha256(key.tobytes()).digest()[:8], "little"))
    low, high = kinematics.lower_limits + GOAL_MARGIN, kinematics.upper_limits - GOAL_MARGIN
    return rng.uniform(low, high, size=(RANDOM_STARTS, len(low)))


def branch_goals(kinematics: Any, q0s: np.ndarray, first_points: np.ndarray) -> list[np.ndarray]:
    """Per sample, the distinct in-limit IK solutions of its first reference point, nearest θ₀ first ``(G, m)``: from
    θ₀ and the :data:`BRANCH_SPREAD` spread configurations, and from :data:`LOCAL_STARTS` configurations near θ₀."""
    q0s = np.asarray(q0s, dtype=float)
    starts = goal_starts(kinematics.lower_limits, kinematics.upper_limits, count=BRANCH_SPREAD, margin=GOAL_MARGIN)
    spread, spread_stops = goals_and_limit_stops(kinematics, q0s, first_points, starts, separation=BRANCH_SEPARATION,
                                                 stop_residual=LIMIT_STOP_RESIDUAL)  # fmt: skip
    count, m = q0s.shape
    offsets = np.random.default_rng(LOCAL_SEED).uniform(-LOCAL_SPREAD, LOCAL_SPREAD, size=(LOCAL_STARTS, m))
    near = np.clip(np.repeat(q0s, LOCAL_STARTS, axis=0) + np.tile(offsets, (count, 1)),
                   kinematics.lower_limits + GOAL_MARGIN, kinematics.upper_limits - GOAL_MARGIN)  # fmt: skip
    # Each local start is its own anchor: the IK ends on the branch through it, near it (no spread starts).
    local, local_stops = goals_and_limit_stops(kinematics, near, np.repeat(first_points, LOCAL_STARTS, axis=0),
                                               np.empty((0, m)), separation=BRANCH_SEPARATION,
                                               stop_residual=LIMIT_STOP_RESIDUAL)  # fmt: skip
    low, high = kinematics.lower_limits + GOAL_MARGIN, kinematics.upper_limits - GOAL_MARGIN
    goals = []
    for i in range(count):
        found = [*spread[i], *(g for j in range(LOCAL_STARTS) for g in local[i * LOCAL_STARTS + j])]
        found = [wrapped_towards(g, q0s[i], low, high) for g in found]
        nearest_first = sorted(found, key=lambda g: float(np.linalg.norm(g - q0s[i])))
        reaching = distinct_configurations(np.array(nearest_first).reshape(-1, m), BRANCH_SEPARATION)
        # After the goals (their names unchanged): the IK ends a limit stopped near the target, not on a branch found.
        stops = [*spread_stops[i], *(g for j in range(LOCAL_STARTS) for g in local_stops[i * LOCAL_STARTS + j])]
        stops = sorted(stops, key=lambda g: float(np.linalg.norm(g - q0s[i])))
        both = distinct_configurations(np.array([*reaching, *stops]).reshape(-1, m), BRANCH_SEPARATION)
        goals.append(both)
    return goals


def wrapped_towards(goal: np.ndarray, q0: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``goal`` with each joint turned by the whole turns (2π) that bring it nearest ``q0`` inside [``lower``,
    ``upper``]: the same end effector, the joint going the other way round. The IK from a start ends at the solution
    nearest that start, and a joint with a range over 2π can reach it either way; the shorter way can be the cheaper
    basin (a held-out track sample: the shoulder 3.2 rad one way, 3.1 the other; IPOPT from rest found it, 0.9 %
    below every start without it)."""
    candidates = goal + 2.0 * np.pi * np.arange(-2, 3)[:, None]  # (5, m): the turns a ±2π range allows
    distance = np.where((candidates >= lower) & (candidates <= upper), np.abs(candidates - q0), np.inf)
    distance[2] = np.abs(goal - q0)  # no turn: the goal itself, always a candidate
    return candidates[np.argmin(distance, axis=0), np.arange(len(goal))]


def needs_branches(kinematics: Any, rest: Any, path: np.ndarray, x_d: np.ndarray) -> bool:
    """Whether a sample's solve from rest (an :class:`~snac_gym.control.trajopt.OptimalSolution` whose joint path is
    ``path``, ``(K + 1, m)``, for the reference ``x_d``, ``(K, 3)``) leaves room for another branch: it travelled to
    the reference's last point, or a limit stopped it, or (a moving reference) its path comes near a singular arm
    (module docs)."""
    if rest.bounded or float(np.linalg.norm(kinematics.forward(path[-1]) - x_d[-1])) <= REACHED:
        return True
    if not np.any(x_d != x_d[:1]):
        return False
    jacobians = np.asarray(kinematics.jacobian_batch(np.ascontiguousarray(path[: len(x_d) : SINGULAR_STRIDE])))
    return float(np.linalg.svd(jacobians, compute_uv=False)[:, -1].min()) < NEAR_SINGULAR


def worth_trying(goal: np.ndarray, q0: np.ndarray, horizon_s: float, ends: list[np.ndarray], best_cost: float) -> bool:
    """Whether a branch's goal could hold a cheaper optimum (module docs): not a known optimum's branch, and not
    so far that the effort of getting there alone costs more than ``best_cost``."""
    if any(float(np.abs(goal - end).max()) < BRANCH_SEPARATION for end in ends):
        return False
    travel = max(0.0, float(np.linalg.norm(goal - q0)) - BRANCH_SEPARATION)
    return travel**2 / horizon_s < best_cost


def branch_commands(
    kinematics: Any, q0s: np.ndarray, goals: np.ndarray, x_d: np.ndarray, dt: float, velocity_limits: np.ndarray
) -> np.ndarray:
    """The start towards each goal, batched: ``(B, K, m)`` for θ₀ ``(B, m)``, goals ``(B, m)`` and references
    ``(B, K, 3)``. The virtual arm moves only where the reference does (a reach's target is fixed)."""
    count, steps = x_d.shape[:2]
    limits = np.asarray(velocity_limits, dtype=float)
    moving = bool(np.any(x_d != x_d[:, :1]))
    arms = GoalArms(kinematics, limits, dt, moving=moving)
    arms.q, arms.found = np.array(goals, dtype=float), np.ones(count, dtype=bool)
    q = np.array(q0s, dtype=float)
    commands = np.empty((count, steps, q.shape[1]))
    if not moving:  # the goals stay put and feed no velocity forward: the law alone, without the arms' step
        for k in range(steps):
            commands[:, k] = scale_rows_into_limits(BRANCH_GAIN * (arms.q - q), limits)
            q = joint_step(q, commands[:, k], dt)
        return commands
    xdot_d = np.gradient(x_d, dt, axis=1)
    for k in range(steps):  # the joint-goal law (baselines/joint_goal.py) towards a goal given here
        goal, velocity = arms.step(x_d[:, k], xdot_d[:, k])
        commands[:, k] = scale_rows_into_limits(velocity + BRANCH_GAIN * (goal - q), limits)
        q = joint_step(q, commands[:, k], dt)
    return commands


def branch_candidates(
    kinematics: Any,
    q0s: list[np.ndarray],
    x_d: np.ndarray,
    dt: float,
    velocity_limits: np.ndarray,
    rest_ends: list[np.ndarray],
    rest_costs: list[float],
    factor: int = 1,
) -> list[dict[str, np.ndarray]]:
    """Per sample, the branch starts worth screening (:func:`worth_trying` against the solve from rest), by name.

    ``x_d``: ``(B, K, 3)`` on the grid of Δt = ``dt``; ``factor``: the starts' commands on its coarse grid (every
    ``factor``-th point, Δt × ``factor``), where :func:`~snac_gym.evaluation.reference.optimum.multi_start_solve`
    screens them.
    """
    horizon = x_d.shape[1] * dt
    x_d, dt = x_d[:, ::factor], dt * factor
    steps = x_d.shape[1]
    goals = branch_goals(kinematics, np.array(q0s), x_d[:, 0])
    kept = [(i, j, goal) for i, found in enumerate(goals) for j, goal in enumerate(found)
            if worth_trying(goal, q0s[i], horizon, [rest_ends[i]], rest_costs[i])]  # fmt: skip
    drawn = [
        (i, j, q)
        for i in range(len(q0s))
        for j, q in enumerate(random_configurations(kinematics, q0s[i], x_d[i, 0]))
        if worth_trying(q, q0s[i], horizon, [rest_ends[i]], rest_costs[i])
    ]
    candidates: list[dict[str, np.ndarray]] = [{} for _ in q0s]
    if kept:
        rows = np.array([i for i, _, _ in kept])
        commands = branch_commands(kinematics, np.array(q0s)[rows], np.array([g for _, _, g in kept]), x_d[rows], dt,
                                   velocity_limits)  # fmt: skip
        for (i, j, _), start in zip(kept, commands, strict=True):
            candidates[i][f"{BRANCH_PREFIX}{j}"] = start
    if drawn:
        rows = np.array([i for i, _, _ in drawn])
        resting = np.repeat(x_d[rows, :1], steps, axis=1)  # a fixed point: the arm goes to its configuration and stays
        commands = branch_commands(kinematics, np.array(q0s)[rows], np.array([q for _, _, q in drawn]), resting, dt,
                                   velocity_limits)  # fmt: skip
        commands[:, steps // 2 :] = 0.0
        for (i, j, _), start in zip(drawn, commands, strict=True):
            candidates[i][f"{RANDOM_PREFIX}{j}"] = start
    return candidates


__all__ = [
    "BRANCH_PREFIX", "BRANCH_SEPARATION", "BRANCH_SPREAD", "LIMIT_STOP_RESIDUAL", "LOCAL_SEED", "LOCAL_SPREAD",
    "LOCAL_STARTS", "NEAR_SINGULAR", "RANDOM_PREFIX", "RANDOM_STARTS", "REACHED", "SINGULAR_STRIDE",
    "branch_candidates", "branch_commands", "branch_goals", "needs_branches", "random_configurations", "worth_trying",
    "wrapped_towards",
]  # fmt: skip
