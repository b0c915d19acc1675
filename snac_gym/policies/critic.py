"""The quadratic critic's parts: its basis σ(s) with the gradient ∇σ, and the episode reset of the critic-based
policies.

Shared by SNAC (:mod:`snac_gym.policies.snac`) and snac-hjb (:mod:`snac_gym.policies.snac_hjb`), which share the
critic V̂(s) = Ŵᵀσ(s) and nothing else.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CriticEpisode", "QuadraticBasis", "matvec", "transpose"]


def matvec(matrices: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``A @ x`` for one matrix and vector; row by row for stacks ``(B, r, c)``, ``(B, c)``."""
    product: np.ndarray = matrices @ vectors if vectors.ndim == 1 else (matrices @ vectors[..., None])[..., 0]
    return product


def transpose(matrices: np.ndarray) -> np.ndarray:
    """``Aᵀ`` of one matrix, or of each matrix of a stack."""
    return matrices.T if matrices.ndim == 2 else np.swapaxes(matrices, -1, -2)


class QuadraticBasis:
    """All degree-2 monomials of a ``dim``-vector: ``σ(s) = [s_i s_j for i ≤ j]``.

    The order is the paper's: ``s₁², s₁s₂, …, s₁s_d, s₂², s₂s₃, …, s_d²`` (6 terms for
    ``d = 3``, 21 for ``d = 6``); ``size = d(d + 1)/2``. The gradient ``∇σ`` (``size × d``,
    row k = ∂σ_k/∂s) is linear in s with a fixed sparse structure, so it is computed as one
    product ``vec(∇σ(s)) = T s`` with the constant selection matrix ``T`` built here.

    Args:
        dim: Dimension of ``s``.
    """

    def __init__(self, dim: int) -> None:
        if dim < 1:
            raise ValueError(f"basis dimension must be positive, got {dim}")
        self.dim = int(dim)
        pairs = [(i, j) for i in range(dim) for j in range(i, dim)]
        self.size = len(pairs)
        #: ``first[k], second[k]``: the indices (i ≤ j) of term k.
        self.first = np.array([i for i, _ in pairs], dtype=np.intp)
        self.second = np.array([j for _, j in pairs], dtype=np.intp)
        # Term k = s_i s_j: ∂/∂s_i = s_j and ∂/∂s_j = s_i (i ≠ j), or ∂/∂s_i = 2 s_i (i = j).
        selection = np.zeros((self.size * dim, dim))
        for k, (i, j) in enumerate(pairs):
            selection[k * dim + i, j] += 1.0
            selection[k * dim + j, i] += 1.0
        #: The constant ``(size·dim, dim)`` matrix T with ``vec(∇σ(s)) = T s``.
        self.selection = selection

    def labels(self, names: list[str] | None = None) -> list[str]:
        """Readable names of the terms, e.g. ``["s0^2", "s0*s1", ...]``."""
        names = names or [f"s{i}" for i in range(self.dim)]
        return [f"{names[i]}^2" if i == j else f"{names[i]}*{names[j]}" for i, j in zip(self.first, self.second)]

    def __call__(self, s: np.ndarray) -> np.ndarray:
        """``σ(s)``, shape ``(size,)``."""
        s = np.asarray(s, dtype=float)
        features: np.ndarray = s[self.first] * s[self.second]
        return features

    def gradient(self, s: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``∇σ(s) = ∂σ/∂s``, shape ``(size, dim)``; for a stack of points ``(B, dim)``, ``(B, size, dim)``.

        Every entry is one ``s_j`` or ``2 s_i``, so the result is exact whatever the shape.

        Args:
            s: The point, shape ``(dim,)`` (or ``(B, dim)``), float64.
            out: Optional C-contiguous float64 ``(size, dim)`` array to write into (one point only).
        """
        if s.ndim == 2:
            return (s @ self.selection.T).reshape(len(s), self.size, self.dim)
        if out is None:
            out = np.empty((self.size, self.dim))
        np.dot(self.selection, s, out=out.reshape(-1))
        return out


class CriticEpisode:
    """``reset`` of the critic-based policies: the step counter to 0 and the critic weights to Ŵ₀,
    drawn by the class's ``_initial_weights(rng)`` from ``seed`` (when given)."""

    _rng: np.random.Generator
    internals: dict[str, Any]

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: step counter to 0, critic weights to Ŵ₀ (drawn from ``seed`` where random)."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.critic_weights = self._initial_weights(self._rng)
        self._k = 0
        self._ready = True
        self.internals = {"critic_weights": self.critic_weights}

    def _initial_weights(self, rng: np.random.Generator) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError
