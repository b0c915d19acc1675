"""Each compiled kernel against the library call it replaced, timed in the same run, one core.

    python docs/scripts/kernel_speed.py

* ``chain_forward_and_jacobian`` (f(θ) and J(θ) of B configurations) against Pinocchio called per
  configuration (``computeFrameJacobian``), the path for models the kernel does not take;
* ``symmetric_eigh`` (3×3) against ``np.linalg.eigh`` of the stack;
* ``thin_svd`` (3×6) against ``np.linalg.svd(..., full_matrices=False)`` of the stack;
* ``frozen_lqr_factors`` (``FrozenJacobianLQR.factors``) against the NumPy products around the
  compiled eigh that it replaced;
* ``add_jacobian_blocks`` (the optimum's Gauss-Newton band, a 2500-step track trajectory) against the
  NumPy products and scattered ``+=`` it replaced.

Each figure is the best of 5 repeats (after a warm-up call that compiles or loads the kernel).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin
from threadpoolctl import threadpool_limits

from snac_gym.control.optimality import SINGULAR_TOLERANCE, FrozenJacobianLQR
from snac_gym.kernels.chain import chain_forward_and_jacobian
from snac_gym.kernels.small import symmetric_eigh, thin_svd
from snac_gym.kernels.trajopt import add_jacobian_blocks
from snac_gym.model.kinematics import shared_kinematics

BATCH = 500


def best_of(function: Callable[[], object], repeats: int = 5, calls: int = 20) -> float:
    function()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        for _ in range(calls):
            function()
        times.append((time.perf_counter() - started) / calls)
    return min(times)


def numpy_band(base: np.ndarray, jacobians: np.ndarray, scale: float) -> np.ndarray:
    steps, _, m = jacobians.shape
    rows, cols = np.tril_indices(m)
    target = ((rows - cols)[None] * (base.shape[1]) + np.arange(steps - 1)[:, None] * m + cols[None]).ravel()
    band = base.copy()
    tail = jacobians[1:]
    pairs = sum(tail[:, i, rows] * tail[:, i, cols] for i in range(tail.shape[1]))
    band.reshape(-1)[target] += scale * pairs.reshape(-1)
    return band


def numpy_factors(lqr: FrozenJacobianLQR, jacobians: np.ndarray) -> tuple[np.ndarray, ...]:
    """``FrozenJacobianLQR.factors`` as it was before its one-pass kernel."""
    weighted = lqr.Q_half @ jacobians
    weighted_t = np.swapaxes(weighted, -1, -2)
    values, vectors = symmetric_eigh(np.ascontiguousarray(weighted @ lqr.R_inverse @ weighted_t))
    singular = values <= SINGULAR_TOLERANCE * values[..., -1:]
    values = np.where(singular, np.inf, values)
    return lqr.R_inverse @ weighted_t @ vectors, values, np.swapaxes(vectors, -1, -2) @ lqr.Q_half, singular


def main() -> None:
    threadpool_limits(1)
    rng = np.random.default_rng(0)
    kinematics = shared_kinematics("ur10")
    qs = rng.uniform(-np.pi, np.pi, (BATCH, 6))
    model, data, frame = kinematics.model, kinematics.data, kinematics._ee_id

    def pinocchio_loop() -> None:
        for q in qs:
            pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)

    arrays = kinematics._chain._kernel_arrays
    rows = [
        (
            "f(θ), J(θ) of a UR10",
            lambda: chain_forward_and_jacobian(qs, *arrays),
            pinocchio_loop,
            "Pinocchio per configuration",
        )
    ]
    jacobians = kinematics.jacobian_batch(qs)
    grams = np.ascontiguousarray(jacobians @ jacobians.transpose(0, 2, 1))
    rows.append(("eigh, 3×3", lambda: symmetric_eigh(grams), lambda: np.linalg.eigh(grams), "np.linalg.eigh"))
    rows.append(
        (
            "SVD, 3×6",
            lambda: thin_svd(jacobians),
            lambda: np.linalg.svd(jacobians, full_matrices=False),
            "np.linalg.svd",
        )
    )
    lqr = FrozenJacobianLQR(9.0 * np.eye(3), None, 3, 6)  # the lqr controller's weights
    rows.append(("LQR factors", lambda: lqr.factors(jacobians), lambda: numpy_factors(lqr, jacobians),
                 "NumPy products around the compiled eigh"))  # fmt: skip
    print(f"{'kernel':24s} {'compiled µs/item':>17s} {'peer µs/item':>13s}  peer")
    for name, compiled, peer, label in rows:
        print(f"{name:24s} {best_of(compiled) / BATCH * 1e6:17.3f} {best_of(peer) / BATCH * 1e6:13.3f}  {label}")
    steps = 2500
    trajectory = kinematics.jacobian_batch(rng.uniform(-np.pi, np.pi, (steps, 6)))
    base = np.asfortranarray(rng.normal(size=(13, steps * 6)))

    c_base = np.ascontiguousarray(base)
    np.testing.assert_array_equal(compiled_band(base, trajectory), numpy_band(c_base, trajectory, 0.016))  # same sums
    compiled = best_of(lambda: compiled_band(base, trajectory))
    peer = best_of(lambda: numpy_band(c_base, trajectory, 0.016))
    print(
        f"{'Gauss-Newton band':24s} {compiled * 1e3:14.3f} ms {peer * 1e3:10.3f} ms  NumPy products and "
        "scattered += (2500 steps)"
    )


def compiled_band(base: np.ndarray, trajectory: np.ndarray) -> np.ndarray:
    band = np.array(base, order="F")  # the solver's copy, in LAPACK's layout
    add_jacobian_blocks(band, trajectory, 0.016)
    return band


if __name__ == "__main__":
    main()
