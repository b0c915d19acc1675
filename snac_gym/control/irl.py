"""Off-policy integral reinforcement learning: the LQR optimum from measured data, without A or B.

Y. Jiang and Z.-P. Jiang, "Computational adaptive optimal control for continuous-time linear
systems with completely unknown dynamics", Automatica 48(10), 2699–2704, 2012. For
``ẋ = A x + B u`` and the cost ``∫ xᵀQx + uᵀRu``, Kleinman's policy iteration (the paper's
Theorem 1)::

    (A − BK_k)ᵀP_k + P_k(A − BK_k) + Q + K_kᵀRK_k = 0,   K_{k+1} = R⁻¹BᵀP_k        (eqs. 6–7)

needs A and B. Along *any* measured trajectory, whatever input u drove it (an exploration signal
included), ``ẋ = A_k x + B(K_k x + u)`` with ``A_k = A − BK_k`` (eq. 9), so on a window [t, t+δt]::

    xᵀP_k x |_t^{t+δt} = −∫ xᵀQ_k x dτ + 2 ∫ (u + K_k x)ᵀ R K_{k+1} x dτ,  Q_k = Q + K_kᵀRK_k   (eq. 10)

which is linear in the unknowns (P_k, K_{k+1}) and contains neither A nor B. Stacking l windows::

    Θ_k [P̂_k; vec K_{k+1}] = Ξ_k                                                       (eq. 11)
    Θ_k = [δ_xx, −2 I_xx (I_n ⊗ K_kᵀR) − 2 I_xu (I_n ⊗ R)],   Ξ_k = −I_xx vec(Q_k)

with the data matrices (one row per window; ``vec`` stacks columns)::

    δ_xx = [x̄(t₁) − x̄(t₀); …],  I_xx = [∫ x⊗x; …],  I_xu = [∫ x⊗u; …]
    x̄ = [x₁², x₁x₂, …, x₁xₙ, x₂², …, xₙ²],  P̂ = [p₁₁, 2p₁₂, …, 2p₁ₙ, p₂₂, …, pₙₙ]   (so xᵀPx = x̄ᵀP̂)

solved by least squares (eq. 12) each iteration from the *same* data, collected once. Under the
rank condition ``rank [I_xx, I_xu] = n(n+1)/2 + mn`` (eq. 13) the solution is unique and equals
Kleinman's iterate (Lemma 6), so from a stabilising K₀ it converges to the ARE's P*, K*
(Theorem 7). The iteration stops when ``‖P_k − P_{k−1}‖ ≤ ε`` (Algorithm 1; spectral norm).

**A measured drift** ``w`` (``ẋ = A x + B u + w``, w known at each instant, e.g. the moving
reference of a tracking error ė = J u − ẋ_d) adds ``2 ∫ wᵀP_k x`` to the left of eq. 10's
derivative; it is linear in P_k and moves to Θ's P̂ columns (``δ_xx − 2 I_xw D``, D the map
P̂ → vec P). With w = 0 this is the paper's eq. 11 unchanged.

:func:`simulate_linear` integrates a linear system with an exploration input together with the
integrals (the paper's example does the same with MATLAB's ode45), for tests and examples;
:func:`windows_from_samples` forms the data from sampled, zero-order-held signals (a controller's).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from snac_gym.control.optimality import quadratic_weights_to_matrix


def _upper(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the upper triangle in the paper's order (row by row: 11, 12, …, 1n, 22, …)."""
    return np.triu_indices(n)


def quadratic_features(x: np.ndarray) -> np.ndarray:
    """x̄ = [x₁², x₁x₂, …, xₙ²] of the rows of ``x`` ``(…, n)``: ``xᵀPx = x̄ᵀP̂``, P̂ the weights of
    :func:`~snac_gym.control.optimality.matrix_to_quadratic_weights` (SNAC's quadratic basis, the paper's vech
    order)."""
    x = np.asarray(x, dtype=float)
    rows, cols = _upper(x.shape[-1])
    return x[..., rows] * x[..., cols]


def _vech_to_vec(n: int) -> np.ndarray:
    """D with ``vec(P) = D P̂`` (``(n², n(n+1)/2)``; vec stacks columns)."""
    rows, cols = _upper(n)
    D = np.zeros((n * n, rows.size))
    for k, (i, j) in enumerate(zip(rows, cols)):
        scale = 1.0 if i == j else 0.5
        D[i + j * n, k] = scale
        D[j + i * n, k] = scale
    return D


@dataclass(frozen=True)
class IRLData:
    """The data of l windows (eq. 11's δ_xx, I_xx, I_xu; I_xw for a measured drift).

    Attributes:
        delta_xx: ``(l, n(n+1)/2)``, x̄(t_j) − x̄(t_{j−1}).
        I_xx: ``(l, n²)``, ∫ x⊗x over each window.
        I_xu: ``(l, nm)``, ∫ x⊗u over each window.
        I_xw: ``(l, n²)``, ∫ x⊗w (zeros without a drift).
    """

    delta_xx: np.ndarray
    I_xx: np.ndarray
    I_xu: np.ndarray
    I_xw: np.ndarray | None = None

    def __post_init__(self) -> None:
        rows = self.delta_xx.shape[0]
        n = int(round(np.sqrt(self.I_xx.shape[1])))
        if n * n != self.I_xx.shape[1] or self.delta_xx.shape[1] != n * (n + 1) // 2:
            raise ValueError(f"delta_xx {self.delta_xx.shape} and I_xx {self.I_xx.shape} do not fit one state size")
        if self.I_xx.shape[0] != rows or self.I_xu.shape[0] != rows or self.I_xu.shape[1] % n:
            raise ValueError(
                f"I_xx {self.I_xx.shape} and I_xu {self.I_xu.shape} need {rows} rows and n = {n} columns per input"
            )
        if self.I_xw is not None and self.I_xw.shape != (rows, n * n):
            raise ValueError(f"I_xw must have shape {(rows, n * n)}, got {self.I_xw.shape}")

    @property
    def state_dim(self) -> int:
        return int(round(np.sqrt(self.I_xx.shape[1])))

    @property
    def input_dim(self) -> int:
        return self.I_xu.shape[1] // self.state_dim

    @property
    def windows(self) -> int:
        return self.delta_xx.shape[0]

    def rank(self) -> int:
        """rank [I_xx, I_xu] (eq. 13 asks for n(n+1)/2 + mn; I_xx has only n(n+1)/2 distinct columns)."""
        n = self.state_dim
        rows, cols = _upper(n)
        distinct = self.I_xx[:, rows * n + cols]  # x⊗x repeats xᵢxⱼ; keep one of each pair
        return int(np.linalg.matrix_rank(np.hstack([distinct, self.I_xu])))


@dataclass
class IRLResult:
    """What :func:`policy_iteration` returns.

    Attributes:
        P: P_0, P_1, … (one per least-squares solve), each ``(n, n)``.
        K: K_0 (the given gain), K_1, …: ``K[k+1]`` is solved with ``P[k]``.
        iterations: Least-squares solves run (``len(P)``).
        converged: Whether ``‖P_k − P_{k−1}‖ ≤ tolerance`` was reached.
        differences: ``‖P_k − P_{k−1}‖`` for k ≥ 1 (spectral norm).
    """

    P: list[np.ndarray] = field(default_factory=list)
    K: list[np.ndarray] = field(default_factory=list)
    iterations: int = 0
    converged: bool = False
    differences: list[float] = field(default_factory=list)

    @property
    def P_final(self) -> np.ndarray:
        return self.P[-1]

    @property
    def K_final(self) -> np.ndarray:
        return self.K[-1]


def _weight(name: str, value: np.ndarray, size: int) -> np.ndarray:
    """``value`` as a symmetric ``(size, size)`` matrix (a length-size vector: its diagonal)."""
    matrix = np.asarray(value, dtype=float)
    if matrix.ndim == 1:
        matrix = np.diag(matrix)
    if matrix.shape != (size, size) or not np.all(np.isfinite(matrix)) or not np.allclose(matrix, matrix.T):
        raise ValueError(
            f"{name} must be a finite symmetric ({size}, {size}) matrix or its diagonal, got shape {matrix.shape}"
        )
    return matrix


def policy_iteration(
    data: IRLData,
    Q: np.ndarray,
    R: np.ndarray,
    K0: np.ndarray,
    *,
    tolerance: float = 1e-6,
    max_iterations: int = 50,
) -> IRLResult:
    """Algorithm 1 on the data: least squares (eq. 12) for P_k, K_{k+1} until ‖P_k − P_{k−1}‖ ≤ tolerance.

    Args:
        data: The windows (:class:`IRLData`).
        Q: State weight ``(n, n)`` (or its diagonal), symmetric positive semidefinite.
        R: Input weight ``(m, m)`` (or its diagonal), symmetric positive definite.
        K0: The gain the iteration starts from ``(m, n)``; it must stabilise the (unknown) system
            for the limit to be the ARE's (Theorem 7). The data need not come from it.
        tolerance: ε of the stopping rule (spectral norm of P_k − P_{k−1}).
        max_iterations: At most this many least-squares solves.

    Raises:
        ValueError: On weights, a gain or a tolerance of the wrong shape or sign, or data whose
            rank is below eq. 13's (the solution would not be unique).
    """
    n, m = data.state_dim, data.input_dim
    Q = _weight("Q", Q, n)
    R = _weight("R", R, m)
    if np.linalg.eigvalsh(R)[0] <= 0:
        raise ValueError("R must be positive definite")
    K = np.asarray(K0, dtype=float)
    if K.shape != (m, n) or not np.all(np.isfinite(K)):
        raise ValueError(f"K0 must be a finite ({m}, {n}) matrix, got shape {K.shape}")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a positive finite number, got {tolerance!r}")
    if isinstance(max_iterations, bool) or int(max_iterations) != max_iterations or max_iterations < 1:
        raise ValueError(f"max_iterations must be a whole number >= 1, got {max_iterations!r}")
    needed = n * (n + 1) // 2 + m * n
    if data.rank() < needed:
        raise ValueError(
            f"the data's rank [I_xx, I_xu] is {data.rank()}, eq. 13 needs {needed}: excite more or add windows"
        )

    p_columns = data.delta_xx
    if data.I_xw is not None:
        p_columns = p_columns - 2.0 * data.I_xw @ _vech_to_vec(n)  # the drift's 2∫wᵀPx
    eye_n = np.eye(n)
    input_columns = -2.0 * data.I_xu @ np.kron(eye_n, R)  # eq. 11
    result = IRLResult(K=[K])
    for _ in range(int(max_iterations)):
        Q_k = Q + K.T @ R @ K
        theta = np.hstack([p_columns, -2.0 * data.I_xx @ np.kron(eye_n, K.T @ R) + input_columns])  # Θ_k, eq. 11
        xi = -data.I_xx @ Q_k.reshape(-1, order="F")  # Ξ_k
        solution = np.linalg.lstsq(theta, xi, rcond=None)[0]  # eq. 12
        P = quadratic_weights_to_matrix(solution[: n * (n + 1) // 2], n)  # P̂ is the critics' quadratic weights
        K = solution[n * (n + 1) // 2 :].reshape(m, n, order="F")
        result.P.append(P)
        result.K.append(K)
        if len(result.P) > 1:
            difference = float(np.linalg.norm(P - result.P[-2], 2))
            result.differences.append(difference)
            if difference <= tolerance:
                result.converged = True
                break
    result.iterations = len(result.P)
    return result


def windows_from_samples(
    states: np.ndarray, inputs: np.ndarray, dt: float, steps_per_window: int = 1, drifts: np.ndarray | None = None
) -> IRLData:
    """The data of a sampled record: ``states`` x₀…x_N ``(N+1, n)``, ``inputs`` u₀…u_{N−1} ``(N, m)``
    held over each period ``dt`` (zero-order hold, as a controller applies them), optional ``drifts``
    w₀…w_{N−1} ``(N, n)`` held likewise.

    Within a period x is taken linear between its samples (exact for ẋ = B u + w with B frozen over
    the period, the arm's ė = J u): ``∫ x⊗x`` by Simpson's rule (exact for the quadratic),
    ``∫ x⊗u = dt·x̄_mid⊗u``. Consecutive periods are summed into windows of ``steps_per_window``
    (a trailing remainder is dropped).

    Raises:
        ValueError: On shapes that do not fit, or a non-positive ``dt`` or window.
    """
    x = np.asarray(states, dtype=float)
    u = np.asarray(inputs, dtype=float)
    if x.ndim != 2 or u.ndim != 2 or x.shape[0] != u.shape[0] + 1:
        raise ValueError(f"states must be (N+1, n) and inputs (N, m), got {x.shape} and {u.shape}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number, got {dt!r}")
    if isinstance(steps_per_window, bool) or int(steps_per_window) != steps_per_window or steps_per_window < 1:
        raise ValueError(f"steps_per_window must be a whole number >= 1, got {steps_per_window!r}")
    count = u.shape[0] // int(steps_per_window)
    if count < 1:
        raise ValueError(f"{u.shape[0]} periods make no window of {steps_per_window}")
    used = count * int(steps_per_window)
    a, b = x[:used], x[1 : used + 1]
    mid = 0.5 * (a + b)

    def kron_rows(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Row-wise p⊗q, index i·dim(q) + j (np.kron's order)."""
        return np.einsum("ki,kj->kij", p, q).reshape(len(p), -1)

    xx = dt / 6.0 * (kron_rows(a, a) + 4.0 * kron_rows(mid, mid) + kron_rows(b, b))  # Simpson, exact here
    xu = dt * kron_rows(mid, u[:used])
    features = quadratic_features(x[: used + 1 : int(steps_per_window)])

    def windowed(rows: np.ndarray) -> np.ndarray:
        return rows.reshape(count, int(steps_per_window), -1).sum(axis=1)

    xw = None
    if drifts is not None:
        w = np.asarray(drifts, dtype=float)
        if w.shape != (u.shape[0], x.shape[1]):
            raise ValueError(f"drifts must have shape {(u.shape[0], x.shape[1])}, got {w.shape}")
        xw = windowed(dt * kron_rows(mid, w[:used]))
    return IRLData(np.diff(features, axis=0), windowed(xx), windowed(xu), xw)


def simulate_linear(
    A: np.ndarray,
    B: np.ndarray,
    x0: np.ndarray,
    input_signal: Callable[[float, np.ndarray], np.ndarray],
    *,
    window: float,
    windows: int,
    substeps: int = 50,
) -> tuple[IRLData, np.ndarray, np.ndarray]:
    """Simulate ``ẋ = A x + B u(t, x)`` over ``windows`` windows of ``window`` s and collect the data.

    The state is integrated together with ``∫ x⊗x`` and ``∫ x⊗u`` (classical Runge–Kutta, ``substeps``
    steps per window), the augmented system of the paper's own simulation.

    Args:
        A, B: The system ``(n, n)``, ``(n, m)`` (used only to simulate; the learner gets the data).
        x0: Initial state ``(n,)``.
        input_signal: ``u(t, x)`` ``(m,)``, e.g. ``−K₀x + e(t)`` with an exploration signal e.
        window: δt of each window, s.
        windows: l, the number of windows.
        substeps: Integration steps per window.

    Returns:
        The :class:`IRLData`, the times ``(l+1,)`` and the states ``(l+1, n)`` at the window ends.

    Raises:
        ValueError: On shapes that do not fit, or a non-positive window, count or step count.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    x = np.asarray(x0, dtype=float).copy()
    n, m = B.shape
    if A.shape != (n, n) or x.shape != (n,):
        raise ValueError(f"A must be ({n}, {n}) and x0 ({n},) for B of shape {B.shape}, got {A.shape} and {x.shape}")
    if not (np.isfinite(window) and window > 0):
        raise ValueError(f"window must be a positive finite number, got {window!r}")
    for name, value in (("windows", windows), ("substeps", substeps)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")

    def rate(t: float, state: np.ndarray) -> np.ndarray:
        xs = state[:n]
        u = np.asarray(input_signal(t, xs), dtype=float)
        return np.concatenate([A @ xs + B @ u, np.kron(xs, xs), np.kron(xs, u)])

    h = window / substeps
    state = np.concatenate([x, np.zeros(n * n + n * m)])
    times, states, rows = [0.0], [x.copy()], []
    t = 0.0
    for _ in range(int(windows)):
        start = state.copy()
        for _ in range(int(substeps)):
            k1 = rate(t, state)
            k2 = rate(t + h / 2, state + h / 2 * k1)
            k3 = rate(t + h / 2, state + h / 2 * k2)
            k4 = rate(t + h, state + h * k3)
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t += h
        rows.append(state[n:] - start[n:])
        times.append(t)
        states.append(state[:n].copy())
    integrals = np.array(rows)
    trajectory = np.array(states)
    # np.kron(x, x)[i·n + j] = xᵢxⱼ is vec(x xᵀ) too (symmetric); np.kron(x, u)[i·m + j] = xᵢuⱼ is vec(u xᵀ) = x⊗u.
    data = IRLData(np.diff(quadratic_features(trajectory), axis=0), integrals[:, : n * n], integrals[:, n * n :])
    return data, np.array(times), trajectory
