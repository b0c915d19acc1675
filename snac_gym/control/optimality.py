"""The frozen-Jacobian optimum of the paper's problem: one place for its equations.

With θ (hence J) frozen at the current configuration, the error dynamics of ``ẋ = J u`` with a
fixed target are linear, ``ė = J u`` (J ∈ ℝ^{n×m}), and the paper's cost (eq. 6)

    V = ∫₀^∞ eᵀQe + uᵀRu dt

makes this an infinite-horizon LQR with A = 0, B = J. Its value function is quadratic,
``V*(e) = eᵀP*e``, and P* is the positive-definite solution of the algebraic Riccati equation

    0 = AᵀP + PA + Q − P B R⁻¹ Bᵀ P = Q − P G P,        G = J R⁻¹ Jᵀ        (ARE, A = 0)

with the optimal feedback ``u* = −K* e``, ``K* = R⁻¹ Jᵀ P*``. A = 0 makes the ARE a quadratic
matrix equation with a closed form. Writing ``Q^{1/2}`` for the symmetric square root of Q and
``S = Q^{1/2} G Q^{1/2}`` (symmetric positive definite when J has full row rank),

    P* = Q^{1/2} S^{-1/2} Q^{1/2}                                           (closed form)

solves it: ``P*GP* = Q^{1/2} S^{-1/2} (Q^{1/2}GQ^{1/2}) S^{-1/2} Q^{1/2} = Q``, and it is
symmetric positive definite, so it is the stabilising solution (unique). It equals the form
``G^{-1/2} (G^{1/2} Q G^{1/2})^{1/2} G^{-1/2}`` (both are the unique SPD solution); this one needs
one eigendecomposition per J instead of two, because Q^{1/2} is computed once. For Q = R = I
it is ``P* = (JJᵀ)^{-1/2}``.

Every function takes one J ``(n, m)`` or a stack ``(B, n, m)`` (vectors then ``(B, n)``), row
for row identical to the single call. ``Q``/``R`` are ``(n, n)``/``(m, m)`` symmetric positive
definite, a length-n/m diagonal, or ``None`` (identity, the paper's choice).

The SNAC critic ``V̂(e) = Ŵᵀσ(e)`` over the quadratic basis of
:class:`snac_gym.policies.snac.QuadraticBasis` is the quadratic form ``eᵀP̂e`` of
:func:`quadratic_weights_to_matrix`, so it can be compared with ``P*`` (:func:`critic_error`)
and checked against the HJB equation (:func:`hjb_residual`).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from snac_gym.control.cost import quadratic_form, weight_matrix
from snac_gym.control.lower_bounds import (  # noqa: F401  (their names here before lower_bounds.py)
    RELAXATION_FIRST_STEPS,
    RELAXATION_MAX_ITERATIONS,
    RELAXATION_RTOL,
    CostRelaxation,
    certified_cost_lower_bounds,
    following_cost_lower_bounds,
    jacobian_variation_bound,
    reachable_lipschitz_bounds,
    reference_steps,
    regulation_cost_lower_bound,
    solve_cost_relaxation,
    trajectory_cost_lower_bound,
    trajectory_cost_lower_bounds,
)
from snac_gym.kernels.compiled import read_only_view

#: Eigenvalues of ``S = Q^{1/2} J R⁻¹ Jᵀ Q^{1/2}`` below this fraction of the largest are taken as
#: zero: J has lost rank there (σ_min/σ_max ≲ 1e-6 for Q = R = I) and the eigenvalue is rounding.
SINGULAR_TOLERANCE = 1e-12


def positive_definite_weight(matrix: Any, dim: int, name: str) -> np.ndarray:
    """A weight of the cost as a finite symmetric positive-definite ``(dim, dim)`` array.

    Args:
        matrix: ``(dim, dim)`` array, a length-``dim`` diagonal, or ``None`` (identity).
        dim: Its dimension.
        name: Its name in the error messages (``"Q"``, ``"R"``).

    Raises:
        ValueError: On a wrong shape, a non-finite entry, asymmetry or a non-positive eigenvalue.
    """
    try:
        checked = weight_matrix(matrix, dim, name)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a ({dim}, {dim}) matrix or a length-{dim} diagonal: {exc}") from exc
    if checked is None:
        return np.eye(dim)
    if not np.all(np.isfinite(checked)):
        raise ValueError(f"{name} must be finite, got {checked.tolist()}")
    if not np.allclose(checked, checked.T, rtol=1e-12, atol=1e-12 * np.abs(checked).max()):
        raise ValueError(f"{name} must be symmetric, got {checked.tolist()}")
    checked = 0.5 * (checked + checked.T)  # exact symmetry, so eigh and the products stay symmetric
    smallest = float(np.linalg.eigvalsh(checked)[0])
    if not smallest > 0:
        raise ValueError(f"{name} must be positive definite; its smallest eigenvalue is {smallest:.3g}")
    return checked


def _symmetric_power(matrices: np.ndarray, power: float) -> np.ndarray:
    """``M^power`` of symmetric positive-definite matrices (one or a stack) through ``eigh``."""
    values, vectors = np.linalg.eigh(matrices)
    return (vectors * values[..., None, :] ** power) @ np.swapaxes(vectors, -1, -2)


class FrozenJacobianLQR:
    """The LQR of ``ė = J u`` with cost ``∫ eᵀQe + uᵀRu dt`` for given Q and R, at any frozen J.

    Q^{1/2} and R⁻¹ are computed once here; :meth:`solution`, :meth:`gain` and
    :meth:`weighted_pseudoinverse` share one eigendecomposition of
    ``S = Q^{1/2} J R⁻¹ Jᵀ Q^{1/2} = W diag(λ) Wᵀ`` per J (:meth:`factors`). With
    ``A = R⁻¹ Jᵀ Q^{1/2} W`` (m×n) and ``C = Wᵀ Q^{1/2}`` (n×n):

        P*    = Cᵀ diag(λ^{-1/2}) C               (the closed form, module docstring)
        K*    = R⁻¹ Jᵀ P* = A diag(λ^{-1/2}) C    (optimal feedback, u* = −K*e)
        J⁺_R  = R⁻¹ Jᵀ G⁻¹ = A diag(λ⁻¹) C        (R-weighted pseudo-inverse, G⁻¹ = Q^{1/2}S⁻¹Q^{1/2})

    Args:
        Q: Error weight, ``(n, n)`` SPD, a length-n diagonal, or ``None`` (identity).
        R: Effort weight, ``(m, m)`` SPD, a length-m diagonal, or ``None`` (identity).
        task_dim: n.
        n_joints: m.

    Raises:
        ValueError: If Q or R is not finite, symmetric and positive definite of the right size.
    """

    def __init__(self, Q: Any, R: Any, task_dim: int, n_joints: int) -> None:
        self.Q = positive_definite_weight(Q, task_dim, "Q")
        self.R = positive_definite_weight(R, n_joints, "R")
        self.Q_half = np.ascontiguousarray(_symmetric_power(self.Q, 0.5))
        self.R_inverse = np.ascontiguousarray(_symmetric_power(self.R, -1.0))

    def factors(self, jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(A, λ, C, singular)`` of the class docstring for one J or a stack.

        ``singular`` marks eigenvalues below :data:`SINGULAR_TOLERANCE`·λ_max; they are set to +inf
        in ``λ``, so that ``λ^{-1/2}`` and ``λ⁻¹`` are 0 there: at a lost rank no command moves the
        end effector along that direction, so the gain drops it instead of dividing by zero.
        """
        from snac_gym.kernels.lqr import frozen_lqr_factors  # numba: imported where first needed

        jacobian = np.asarray(jacobian, dtype=float)
        shape = jacobian.shape
        n, m = shape[-2:]
        # S = Q^{1/2} J R⁻¹ Jᵀ Q^{1/2} = W diag(λ) Wᵀ, A = R⁻¹ Jᵀ Q^{1/2} W, C = Wᵀ Q^{1/2}: one compiled pass
        left, values, right, singular = frozen_lqr_factors(
            read_only_view(jacobian.reshape(-1, n, m)), self.Q_half, self.R_inverse, SINGULAR_TOLERANCE
        )
        stack = shape[:-2]
        return (
            left.reshape((*stack, m, n)), values.reshape((*stack, n)), right.reshape((*stack, n, n)),
            singular.reshape((*stack, n)),
        )  # fmt: skip

    def solution(self, jacobian: np.ndarray, at_singular: str = "raise") -> np.ndarray:
        """``P*(J)``, the SPD solution of ``0 = Q − P J R⁻¹ Jᵀ P`` (closed form), ``(…, n, n)``.

        Args:
            jacobian: One J or a stack.
            at_singular: ``"raise"`` or ``"nan"`` (the rows of a stack whose J lost rank are NaN;
                for diagnostics of logged trajectories).

        Raises:
            ValueError: If some J has lost rank (``J R⁻¹ Jᵀ`` singular) and ``at_singular`` is
                ``"raise"``: the ARE then has no stabilising solution, the cost of an error along
                the lost direction is infinite.
        """
        _, values, right, singular = self.factors(jacobian)
        lost: np.ndarray = np.asarray(singular.any(axis=-1))
        if lost.any() and at_singular != "nan":
            raise ValueError("J R⁻¹ Jᵀ is singular (J has lost rank): the Riccati equation has no stabilising solution")
        solution = np.swapaxes(right, -1, -2) @ (values[..., :, None] ** -0.5 * right)  # Cᵀ diag(λ^{-1/2}) C
        return np.where(lost[..., None, None], np.nan, solution)

    def gain(self, jacobian: np.ndarray) -> np.ndarray:
        """``K* = R⁻¹ Jᵀ P*(J)``, ``(…, m, n)``; bounded at a singularity (see :meth:`factors`)."""
        left, values, right, _ = self.factors(jacobian)
        return left @ (values[..., :, None] ** -0.5 * right)  # A diag(λ^{-1/2}) C

    def weighted_pseudoinverse(self, jacobian: np.ndarray) -> np.ndarray:
        """``J⁺_R = R⁻¹ Jᵀ (J R⁻¹ Jᵀ)⁻¹``, ``(…, m, n)``: the least-``uᵀRu`` u with ``J u = v`` is ``J⁺_R v``.

        For R = I this is the Moore–Penrose pseudo-inverse J⁺ (full row rank).
        """
        left, values, right, _ = self.factors(jacobian)
        return left @ (values[..., :, None] ** -1.0 * right)  # A diag(λ⁻¹) C


def riccati_solution(jacobian: np.ndarray, Q: Any = None, R: Any = None) -> np.ndarray:
    """``P*(J)``: the SPD solution of the ARE ``0 = Q − P J R⁻¹ Jᵀ P`` (A = 0, B = J).

    ``V*(e) = eᵀP*e`` is the least cost ``∫ eᵀQe + uᵀRu dt`` of ``ė = J u`` from e with J frozen.
    Closed form ``P* = Q^{1/2} (Q^{1/2} J R⁻¹ Jᵀ Q^{1/2})^{-1/2} Q^{1/2}`` (module docstring);
    Q = R = I gives ``(JJᵀ)^{-1/2}``.

    Args:
        jacobian: J, ``(n, m)`` or a stack ``(B, n, m)``, full row rank.
        Q: Error weight (``None``: identity).
        R: Effort weight (``None``: identity).

    Returns:
        P*, ``(n, n)`` or ``(B, n, n)``.

    Raises:
        ValueError: On bad weights, or a J that has lost rank (no stabilising solution).
    """
    jacobian = np.asarray(jacobian, dtype=float)
    return FrozenJacobianLQR(Q, R, *jacobian.shape[-2:]).solution(jacobian)


def lqr_gain(jacobian: np.ndarray, Q: Any = None, R: Any = None) -> np.ndarray:
    """``K* = R⁻¹ Jᵀ P*(J)``: the optimal feedback ``u* = −K* e`` of ``ė = J u`` (J frozen).

    Minimising the HJB Hamiltonian ``∇Vᵀ J u + eᵀQe + uᵀRu`` over u gives ``u = −½ R⁻¹ Jᵀ ∇V``
    (the paper's eq. 15), and ``∇V* = 2P*e``. Closed loop: ``ė = −J K* e = −G P* e``, stable.

    Args:
        jacobian: J, ``(n, m)`` or ``(B, n, m)``.
        Q: Error weight (``None``: identity).
        R: Effort weight (``None``: identity).

    Returns:
        K*, ``(m, n)`` or ``(B, m, n)``; directions J has lost get gain 0.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    return FrozenJacobianLQR(Q, R, *jacobian.shape[-2:]).gain(jacobian)


def hjb_residual(
    value_gradient: np.ndarray,
    jacobian: np.ndarray,
    command: np.ndarray,
    error: np.ndarray,
    Q: Any = None,
    R: Any = None,
) -> np.ndarray:
    """The continuous-time HJB Hamiltonian ``r = ∇V̂ᵀ J u + eᵀQe + uᵀRu`` at (e, u).

    For the true value function and its minimising command the HJB equation
    ``0 = min_u [∇Vᵀ ė + eᵀQe + uᵀRu]`` holds, so ``r = 0`` at ``(∇V*, u*) = (2P*e, −K*e)``
    (``r = eᵀ(Q − P*GP*)e``, the ARE). For a critic V̂ and its command û, r measures how far the
    pair is from satisfying it; for ``V̂ = eᵀP̂e`` pass ``∇V̂ = 2P̂e``.

    Args:
        value_gradient: ∇V̂ at e, ``(n,)`` or ``(B, n)``.
        jacobian: J, ``(n, m)`` or ``(B, n, m)``.
        command: u, ``(m,)`` or ``(B, m)``.
        error: e, ``(n,)`` or ``(B, n)``.
        Q: Error weight (``None``: identity).
        R: Effort weight (``None``: identity).

    Returns:
        r, a float array of shape ``()`` or ``(B,)``.
    """
    error = np.asarray(error, dtype=float)
    if error.ndim == 1:  # as a stack of one: quadratic_form's 1-D shortcut rounds differently from its stack path
        return hjb_residual(
            np.asarray(value_gradient)[None], np.asarray(jacobian)[None], np.asarray(command)[None], error[None], Q, R
        )[0]
    command = np.asarray(command, dtype=float)
    velocity = (np.asarray(jacobian, dtype=float) @ command[..., None])[..., 0]  # ė = J u
    error_cost = quadratic_form(error, weight_matrix(Q, error.shape[-1], "Q"))
    effort_cost = quadratic_form(command, weight_matrix(R, command.shape[-1], "R"))
    return np.einsum("...i,...i->...", np.asarray(value_gradient, dtype=float), velocity) + error_cost + effort_cost


def relative_hjb_residual(
    value_gradient: np.ndarray,
    jacobian: np.ndarray,
    command: np.ndarray,
    error: np.ndarray,
    Q: Any = None,
    R: Any = None,
) -> np.ndarray:
    """``r / eᵀQe``: :func:`hjb_residual` scaled by the error cost, comparable across error sizes.

    r and eᵀQe are both quadratic in e for a quadratic critic and a linear command, so the ratio
    depends on the direction of e only. Undefined (inf/nan) at e = 0.
    """
    error = np.asarray(error, dtype=float)
    residual = hjb_residual(value_gradient, jacobian, command, error, Q, R)
    stack = error.reshape(-1, error.shape[-1])  # the stack path of quadratic_form for one e too, as above
    return residual / quadratic_form(stack, weight_matrix(Q, error.shape[-1], "Q")).reshape(error.shape[:-1])


def critic_error(P_hat: np.ndarray, P_star: np.ndarray) -> np.ndarray:
    """Relative Frobenius distance ``‖P̂ − P*‖_F / ‖P*‖_F`` of one pair or a stack ``(B, n, n)``."""
    P_hat = np.asarray(P_hat, dtype=float)
    P_star = np.asarray(P_star, dtype=float)
    return np.linalg.norm(P_hat - P_star, axis=(-2, -1)) / np.linalg.norm(P_star, axis=(-2, -1))


@functools.lru_cache(maxsize=16)
def _basis_pairs(dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j), i ≤ j, of the quadratic basis terms ``s_i s_j`` in SNAC's order.

    ``np.triu_indices`` lists the upper triangle row by row: s₁², s₁s₂, …, s₁s_d, s₂², …, s_d², the
    order of :class:`snac_gym.policies.snac.QuadraticBasis` (tested against it).
    """
    if dim < 1:
        raise ValueError(f"dimension must be positive, got {dim}")
    first, second = np.triu_indices(dim)  # cached: the critics convert their weights several times a step
    first.setflags(write=False)
    second.setflags(write=False)
    return first, second


def quadratic_weights_to_matrix(weights: np.ndarray, dim: int) -> np.ndarray:
    """The symmetric P̂ with ``eᵀP̂e = Ŵᵀσ(e)`` for weights of SNAC's quadratic basis.

    ``σ(e) = [e_i e_j for i ≤ j]`` (row-major upper triangle), so
    ``Ŵᵀσ(e) = Σ_i W_ii e_i² + Σ_{i<j} W_ij e_i e_j`` and ``P̂_ii = W_ii``, ``P̂_ij = P̂_ji = W_ij / 2``.

    Args:
        weights: Ŵ, ``(d(d+1)/2,)`` or a stack ``(B, d(d+1)/2)``.
        dim: d, the dimension of the critic state (3 for reach, 6 for the tracking ξ).

    Returns:
        P̂, ``(d, d)`` or ``(B, d, d)``.

    Raises:
        ValueError: If the last axis of ``weights`` is not d(d+1)/2 long.
    """
    weights = np.asarray(weights, dtype=float)
    first, second = _basis_pairs(dim)
    if weights.shape[-1:] != first.shape:
        raise ValueError(f"a quadratic basis in {dim} variables has {len(first)} weights, got shape {weights.shape}")
    halves = np.where(first == second, weights, 0.5 * weights)  # a cross term s_i s_j is split over P_ij and P_ji
    matrix = np.zeros(weights.shape[:-1] + (dim, dim))
    matrix[..., first, second] = halves
    matrix[..., second, first] = halves
    return matrix


def matrix_to_quadratic_weights(matrix: np.ndarray) -> np.ndarray:
    """The inverse of :func:`quadratic_weights_to_matrix`: Ŵ with ``Ŵᵀσ(e) = eᵀPe``.

    ``W_ii = P_ii`` and ``W_ij = P_ij + P_ji`` (i < j); exact for any square P, since ``eᵀPe``
    only sees its symmetric part.

    Args:
        matrix: P, ``(d, d)`` or ``(B, d, d)``.

    Returns:
        Ŵ, ``(d(d+1)/2,)`` or ``(B, d(d+1)/2)``.
    """
    matrix = np.asarray(matrix, dtype=float)
    if matrix.ndim < 2 or matrix.shape[-1] != matrix.shape[-2]:
        raise ValueError(f"P must be square, got shape {matrix.shape}")
    first, second = _basis_pairs(matrix.shape[-1])
    upper, lower = matrix[..., first, second], matrix[..., second, first]
    return np.where(first == second, upper, upper + lower)
