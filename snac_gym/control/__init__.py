"""Control theory and optimisation: the trajectory cost, the per-sample trajectory optimiser, the frozen-Jacobian
LQR/HJB optimum with its certified lower bounds, and integral RL."""
