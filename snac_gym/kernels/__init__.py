"""The compiled kernels (numba), in one place: f and J of a chain (:mod:`~snac_gym.kernels.chain`), 3×3 eigh and
3×6 SVD (:mod:`~snac_gym.kernels.small`), the frozen-Jacobian LQR factors (:mod:`~snac_gym.kernels.lqr`), the
rollout metrics (:mod:`~snac_gym.kernels.metrics`), SNAC-HJB's residual law (:mod:`~snac_gym.kernels.hjb`),
snac-adaptive's corrected chain (:mod:`~snac_gym.kernels.identifier`), the
trajectory optimiser's Gauss-Newton band (:mod:`~snac_gym.kernels.trajopt`) and the certified lower bound
(:mod:`~snac_gym.kernels.relaxation`). :mod:`~snac_gym.kernels.compiled` holds stop signals while one compiles and
warms them up before a real-time loop. The bottom layer: these import nothing else of the package."""
