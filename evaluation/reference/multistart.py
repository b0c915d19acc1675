"""The reference's multi-start search for one sample: the solve from rest, then every candidate start screened on a
coarse time grid and the cheapest few polished on the full grid (:func:`multi_start_solve`).

The cost is not convex (the arm can reach a target the other way round, on another IK branch), so a local solve finds
*a* local optimum; the candidates are the reference's own starts and its IK-branch and random starts
(:mod:`~snac_gym.evaluation.reference.optimum`, :mod:`~snac_gym.evaluation.reference.branches`), drawn from the
sample alone. The method and its figures: docs/optimal.md.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import (
    FTOL,
    GTOL,
    Limits,
    OptimalSolution,
    angles,
    gauss_newton,
    position_bounds,
    solve_sample,
)

#: The screen's coarse time grid: every COARSE_FACTOR-th step of the horizon, Δt × COARSE_FACTOR
#: (:func:`coarse_problem`). Each start is solved there first, on a tenth of the variables.
COARSE_FACTOR = 10
#: Gauss-Newton steps on the coarse grid a start is screened by before it is solved there to the end; the screen, and
#: that solve, stop at once where the start reaches a known optimum's basin.
SCREEN_ITERATIONS = 10
#: Iteration cap of each coarse solve (Gauss-Newton, and each interior-point barrier start where a limit binds).
COARSE_ITERATIONS = 300
#: Coarse optima (the cheapest first) that are solved on the full grid (polished), at most.
POLISHED = 2
#: A coarse optimum is polished only where its coarse cost is below (1 + SCREEN_MARGIN) times the coarse cost of
#: the best optimum's basin.
SCREEN_MARGIN = 0.1
#: A screened start whose joint path comes within this distance (max |Δθ| over the horizon, rad) of a local
#: optimum already found is in that optimum's basin and is not solved again. Distinct local optima lie on
#: other IK branches or windings, radians apart; starts that end in the same optimum come within 0.1 rad of it
#: after one to three Gauss-Newton steps (measured on cuboid and workspace samples, docs/optimal.md).
BASIN_RADIUS = 0.1
#: Every solve of the multi-start takes Newton's step wherever the exact Hessian is positive definite, Gauss-Newton's
#: elsewhere (``gauss_newton(newton=True)``). Gauss-Newton alone converged linearly wherever the errors stay large along
#: the path: 44 % of its steps on Table I's reach samples were those of coarse solves whose steps shrank by 0.88 each
#: (``python docs/scripts/screen_tails.py RUN 250 --gauss-newton``), and it stopped there with the cost up to a few
#: 1e-7 above the optimum.
NEWTON = True
#: Name of the start at rest (U = 0) in ``optimal_winner``.
REST_START = "rest"


@dataclass
class MultiStart:
    """The best of several local optima of one sample.

    Attributes:
        solution: The winning solve.
        winner: Its start: :data:`REST_START` or the name of one of :data:`OWN_STARTS`.
        starts: How many solves ran.
        spread: (worst − best) / best over the local optima found (0 with one start).
        same_basin: Candidates whose screen reached the basin of an optimum already found (not solved again).
    """

    solution: OptimalSolution
    winner: str
    starts: int
    spread: float
    same_basin: int = 0


def coarse_commands(commands: np.ndarray, factor: int) -> np.ndarray:
    """``commands`` ``(K, m)`` block-averaged over ``factor`` steps, ``(⌈K/factor⌉, m)``: on the coarse grid of
    :func:`multi_start_solve` (Δt × factor) they pass through the same angles at every factor-th step."""
    steps = len(commands)
    blocks = np.arange(0, steps, factor)
    return np.add.reduceat(commands, blocks, axis=0) / np.diff(np.append(blocks, steps))[:, None]


def _coarse_screen(
    q0: np.ndarray,
    coarse_x: np.ndarray,
    kinematics: Any,
    coarse_dt: float,
    convention: CostConvention,
    coarse_solve: Any,
    in_coarse_basin: Any,
    start: np.ndarray,
) -> OptimalSolution | None:
    """A candidate's optimum on the coarse grid of :func:`multi_start_solve` from its coarse commands ``start``, or None
    where its screen reaches a known optimum's basin (after :data:`SCREEN_ITERATIONS` Gauss-Newton steps, or at the end
    of the coarse solve)."""
    stepped, *_ = gauss_newton(q0, coarse_x, kinematics, coarse_dt, start, GTOL, FTOL, SCREEN_ITERATIONS, convention,
                               until=in_coarse_basin, gradient=False, newton=NEWTON)  # fmt: skip
    if in_coarse_basin(stepped):
        return None
    coarse = coarse_solve(initial=stepped, interior_start=start, until=in_coarse_basin)
    return None if in_coarse_basin(coarse.commands) else coarse


class _Basins:
    """The local optima a multi-start has found, by their joint paths: ``fine`` (full grid, the solves) and ``coarse``
    (the coarse grid's optima that screens found there). A start whose path comes within :data:`BASIN_RADIUS` (max
    |Δθ|) of one is in its basin and would end there again: on Table I's reach samples, 154 of the 218 coarse solves
    that ended outside the solve from rest's basin ended in one an earlier start had found."""

    def __init__(self, q0: np.ndarray, dt: float, factor: int, fine: list[np.ndarray]) -> None:
        self.q0, self.dt, self.factor = q0, dt, factor
        self.fine = fine  # the caller's list: it adds each polished optimum
        self.coarse: list[np.ndarray] = []

    def add_coarse(self, commands: np.ndarray) -> None:
        """Know the coarse-grid optimum ``commands`` as a basin."""
        self.coarse.append(angles(commands, self.q0, self.dt * self.factor))

    def near(self, commands: np.ndarray) -> bool:
        """Whether full-grid ``commands`` lead into a known basin."""
        path = angles(commands, self.q0, self.dt)
        return any(float(np.abs(path - known).max()) < BASIN_RADIUS for known in self.fine)

    def near_on_coarse_grid(self, commands: np.ndarray) -> bool:
        """Whether coarse-grid ``commands`` lead into a known basin (the fine paths taken at the grid's points)."""
        path = angles(commands, self.q0, self.dt * self.factor)
        return any(float(np.abs(path - known[:: self.factor]).max()) < BASIN_RADIUS for known in self.fine) or any(
            float(np.abs(path - known).max()) < BASIN_RADIUS for known in self.coarse
        )


def _check_coarse(candidates: dict[str, np.ndarray], shape: tuple[int, int]) -> None:
    for name, commands in candidates.items():
        if np.shape(commands) != shape:
            raise ValueError(
                f"start {name!r}: commands of shape {np.shape(commands)}, expected the coarse grid's {shape} "
                "(coarse_commands of a full-grid sequence)"
            )


def solve_from_rest(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Any,
    dt: float,
    limits: np.ndarray,
    convention: CostConvention,
    position_limits: tuple[np.ndarray, np.ndarray] | None = None,
) -> OptimalSolution:
    """The solve from rest (U = 0), through the coarse grid of :func:`multi_start_solve`: solved there first (a tenth of
    the variables), then on the full grid from that solution repeated over each block's steps.

    From rest the full grid's Gauss-Newton spends its first steps on what the coarse grid settles for a tenth of the
    work; from the coarse optimum it needs about three (on Table I's samples: 3.0 against 5.5, a third less time).
    Where the full grid's unconstrained optimum breaks a limit, the interior point still starts from rest, as the
    solve from rest always did. The optimum reached is the same local optimum to the solver's tolerance (Table I's
    2000 samples: within 5·10⁻⁹ of the solve from rest's), not bit for bit the same.
    """
    steps, factor = len(x_d), COARSE_FACTOR
    if steps < 2 * factor:  # a grid of one or two points says nothing about the path
        return solve_sample(q0, x_d, kinematics, dt, limits, convention=convention, position_limits=position_limits,
                            newton=NEWTON)  # fmt: skip
    coarse = solve_sample(q0, x_d[::factor], kinematics, float(dt) * factor, limits, convention=convention,
                          position_limits=position_limits, newton=NEWTON)  # fmt: skip
    initial = np.repeat(coarse.commands, factor, axis=0)[:steps]
    fine = solve_sample(q0, x_d, kinematics, dt, limits, initial=initial, interior_start=np.zeros_like(initial),
                        convention=convention, position_limits=position_limits, newton=NEWTON)  # fmt: skip
    # The work of both grids in the solver's columns (optimal_iterations, optimal_evaluations, optimal_solve_time).
    return dataclasses.replace(fine, iterations=coarse.iterations + fine.iterations,
                               evaluations=coarse.evaluations + fine.evaluations,
                               seconds=coarse.seconds + fine.seconds)  # fmt: skip


def multi_start_solve(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Any,
    dt: float,
    limits: np.ndarray,
    convention: CostConvention,
    candidates: dict[str, np.ndarray],
    margin: float = SCREEN_MARGIN,
    first: OptimalSolution | None = None,
    position_limits: tuple[np.ndarray, np.ndarray] | None = None,
) -> MultiStart:
    """Solve from rest, then screen every candidate command sequence on a coarse time grid and polish the best few.

    The cost is not convex (the arm can reach a target the other way round, on another IK branch), so
    the solve from rest finds *a* local optimum. A feedback law's trajectory lies in some basin; a
    solve started there descends to that basin's optimum. A candidate's own cost says little about its
    basin (under Table I's cost a feedback law pays mostly for its first command's jump), nor do a few
    unconstrained Gauss-Newton steps where a limit binds (they leave the limits; the interior point from the
    start may end far lower). So each candidate is **screened on the coarse grid** (every
    :data:`COARSE_FACTOR`-th step, Δt × :data:`COARSE_FACTOR`: a tenth of the variables), where it is given:
    :data:`SCREEN_ITERATIONS` Gauss-Newton steps, then solved there to the end (the interior point where a limit
    binds, at most :data:`COARSE_ITERATIONS` iterations); both stop at once where its joint path comes within
    :data:`BASIN_RADIUS` of a local optimum already found, a full-grid solve's or an earlier start's coarse one (it
    is then in that optimum's basin, counted in ``same_basin``). The best optimum's basin is solved on the coarse
    grid too (from its
    commands). The coarse optima are then **polished** on the full grid, the cheapest first, at most
    :data:`POLISHED` of them and only those whose coarse cost is below (1 + ``margin``) × that of the best
    optimum's basin, each from its coarse solution repeated over the steps of its block (which keeps every
    limit that the coarse solution keeps). The candidates are the reference's own (:data:`OWN_STARTS`), never
    the contestants it judges (with the IK-branch and random starts of
    :mod:`~snac_gym.evaluation.reference.branches`, which the caller adds).

    ``candidates``: each start's commands on the coarse grid, ``(⌈K/COARSE_FACTOR⌉, m)`` by name: a feedback law
    rolled out there, or :func:`coarse_commands` of a full-grid sequence (the same angles at the grid's points).
    A start is needed there only: rolling a law out on the full grid would cost ten times the steps for a start
    that the screen's first Gauss-Newton step moves anyway. Where a polish's coarse solution leaves a limit, the
    interior point starts from the candidate's own commands, held over each block.
    ``first``: the solve from rest (:func:`solve_from_rest`), when already made.

    Raises:
        ValueError: If a candidate is not on the coarse grid.
    """
    _check_coarse(candidates, (len(x_d[::COARSE_FACTOR]), len(q0)))  # before any solve: a wrong call fails at once
    solve = functools.partial(solve_sample, q0, x_d, kinematics, dt, limits, convention=convention,
                              position_limits=position_limits, newton=NEWTON)  # fmt: skip
    best = first if first is not None else solve_from_rest(q0, x_d, kinematics, dt, limits, convention, position_limits)
    winner, optima, same_basin = REST_START, [best.cost], 0
    paths = [angles(best.commands, q0, dt)]
    steps, factor = len(x_d), COARSE_FACTOR
    coarse_dt, coarse_x = float(dt) * factor, x_d[::factor]
    coarse_solve = functools.partial(solve_sample, q0, coarse_x, kinematics, coarse_dt, limits, convention=convention,
                                     max_iterations=COARSE_ITERATIONS, position_limits=position_limits,
                                     newton=NEWTON)  # fmt: skip
    box = Limits(np.asarray(limits, dtype=float)) if position_limits is None else Limits(
        np.asarray(limits, dtype=float), *position_bounds(*position_limits, q0))  # fmt: skip

    basins = _Basins(q0, dt, factor, paths)
    in_known_basin, in_coarse_basin = basins.near, basins.near_on_coarse_grid

    screen = functools.partial(_coarse_screen, q0, coarse_x, kinematics, coarse_dt, convention, coarse_solve,
                               in_coarse_basin)  # fmt: skip
    screened: list[tuple[float, str, np.ndarray, np.ndarray]] = []
    for name, commands in candidates.items():
        coarse = screen(commands)
        if coarse is not None:  # its own commands over the full grid: inside every limit its coarse path keeps
            screened.append((coarse.cost, name, coarse.commands, np.repeat(commands, factor, axis=0)[:steps]))
            basins.add_coarse(coarse.commands)
    same_basin += len(candidates) - len(screened)
    if screened:
        incumbent = coarse_solve(initial=coarse_commands(best.commands, factor))
        if not in_coarse_basin(incumbent.commands):  # the coarse solve left the basin: another start of its own
            screened.append((incumbent.cost, winner, incumbent.commands, best.commands))
        screened.sort(key=lambda entry: entry[0])
        for cost, name, coarse_solution, commands in screened[:POLISHED]:
            if not cost < (1.0 + margin) * incumbent.cost:
                break
            initial = np.repeat(coarse_solution, factor, axis=0)[:steps]
            if in_known_basin(initial):
                same_basin += 1
                continue
            inside = initial if box.violation(initial, q0, dt) < 0.0 else commands
            solution = solve(initial=initial, interior_start=inside)
            optima.append(solution.cost)
            paths.append(angles(solution.commands, q0, dt))
            if solution.cost < best.cost:
                best, winner = solution, name
    spread = (max(optima) - min(optima)) / min(optima) if len(optima) > 1 and min(optima) > 0 else 0.0
    return MultiStart(best, winner, len(optima), float(spread), same_basin)


__all__ = [
    "BASIN_RADIUS", "COARSE_FACTOR", "COARSE_ITERATIONS", "NEWTON", "POLISHED", "REST_START", "SCREEN_ITERATIONS",
    "SCREEN_MARGIN",
    "MultiStart", "coarse_commands", "multi_start_solve", "solve_from_rest",
]  # fmt: skip
