"""The simulation example of Jiang & Jiang (Automatica 2012, Sec. 4) with :mod:`snac_gym.control.irl`: the
convergence figure docs/figures/irl_example.png (‖P_k − P*‖ and ‖K_k − K*‖ over the iterations) and
the numbers docs/irl.md quotes.

The system (a turbocharged diesel engine with exhaust gas recirculation, the paper's Box I), Q, R,
K₀ = 0, x₀, the exploration signal (per input, 100·mean of 100 sinusoids of frequencies uniform in
[−500, 500] rad/s), 200 windows of 0.01 s are those of the authors' published MATLAB code
(github.com/yu-jiang/Paper_Automatica2012_CTLTI, Jiang2012Automatica.m); the frequencies are random
there, here drawn from ``numpy.random.default_rng(SEED)``.

    python docs/scripts/irl_example.py [--out docs/figures/irl_example.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

from snac_gym.control.irl import policy_iteration, simulate_linear

A = np.array(
    [
        [-0.4125, -0.0248, 0.0741, 0.0089, 0.0, 0.0],
        [101.5873, -7.2651, 2.7608, 2.8068, 0.0, 0.0],
        [0.0704, 0.0085, -0.0741, -0.0089, 0.0, 0.0200],
        [0.0878, 0.2672, 0.0, -0.3674, 0.0044, 0.3962],
        [-1.8414, 0.0990, 0.0, 0.0, -0.0343, -0.0330],
        [0.0, 0.0, 0.0, -359.0, 187.5364, -87.0316],
    ]
)
B = np.array([[-0.0042, 0.0064], [-1.0360, 1.5849], [0.0042, 0.0], [0.1261, 0.0], [0.0, -0.0168], [0.0, 0.0]])
Q = np.diag([1.0, 1.0, 0.1, 0.1, 0.1, 0.1])
R = np.eye(2)
X0 = np.array([10.0, 2.0, 10.0, 2.0, -1.0, -2.0])
WINDOW, WINDOWS, SUBSTEPS = 0.01, 200, 50
#: The paper's stopping tolerance (Sec. 4) and the authors' code's (1e-10, at most 16 solves).
TOLERANCE, CODE_TOLERANCE, CODE_MAX_ITERATIONS = 0.03, 1e-10, 16
#: The learned gain the paper prints after learning (Sec. 4), four decimals.
PAPER_K = np.array(
    [
        [-0.7952, -0.0684, -0.0725, 0.0242, -0.0488, -0.0002],
        [1.6511, 0.1098, 0.0975, 0.0601, 0.0212, 0.0002],
    ]
)
SEED = 2012


def exploration(seed: int = SEED):
    """e(t) = 100·mean_i sin(ωᵢt) per input, 100 frequencies ωᵢ ~ U(−500, 500) rad/s each (K₀ = 0: u = e)."""
    frequencies = (np.random.default_rng(seed).random((2, 100)) - 0.5) * 1000.0
    return lambda t, x: 100.0 * np.sin(frequencies * t).mean(axis=1)


def run(seed: int = SEED, tolerance: float = TOLERANCE, max_iterations: int = 50):
    """Collect the data and iterate: (result, P*, K*)."""
    data, _, _ = simulate_linear(A, B, X0, exploration(seed), window=WINDOW, windows=WINDOWS, substeps=SUBSTEPS)
    P_star = solve_continuous_are(A, B, Q, R)
    K_star = np.linalg.solve(R, B.T @ P_star)
    result = policy_iteration(data, Q, R, np.zeros((2, 6)), tolerance=tolerance, max_iterations=max_iterations)
    return result, P_star, K_star


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "figures" / "irl_example.png")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result, P_star, K_star = run(tolerance=CODE_TOLERANCE, max_iterations=CODE_MAX_ITERATIONS)
    stop, _, _ = run(tolerance=TOLERANCE)
    p_errors = [np.linalg.norm(P - P_star, 2) for P in result.P]
    k_errors = [np.linalg.norm(K - K_star, 2) for K in result.K]
    print(
        f"eps={TOLERANCE}: {stop.iterations} iterations, |P-P*|={np.linalg.norm(stop.P_final - P_star, 2):.3g}, "
        f"|K-K*|={np.linalg.norm(stop.K_final - K_star, 2):.3g}, "
        f"max|K-K_paper|={np.abs(stop.K_final - PAPER_K).max():.3g}"
    )
    print(
        f"eps={CODE_TOLERANCE}, at most {CODE_MAX_ITERATIONS}: {result.iterations} iterations, "
        f"converged={result.converged}, "
        f"|P_k-P*| = {', '.join(f'{e:.3g}' for e in p_errors)}"
    )
    print(f"|P_k-P_k-1| = {', '.join(f'{d:.3g}' for d in result.differences)}")

    fig, axes = plt.subplots(2, 1, figsize=(6.0, 5.0), sharex=True)
    axes[0].semilogy(range(len(p_errors)), p_errors, "o-", label="‖P_k − P*‖")
    axes[0].axhline(TOLERANCE, color="grey", ls=":", label=f"ε = {TOLERANCE} (paper)")
    axes[1].semilogy(range(len(k_errors)), k_errors, "^-", color="C1", label="‖K_k − K*‖")
    for ax in axes:
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
    axes[1].set_xlabel("iteration k")
    axes[0].set_title("Jiang & Jiang (2012), Sec. 4 example: snac_gym.control.irl", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
