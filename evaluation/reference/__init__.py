"""The `optimal` reference of each sample (its own starts, rollout and columns), its cache by sample content, and
the IPOPT cross-check; the solver itself is :mod:`snac_gym.control.trajopt`."""
