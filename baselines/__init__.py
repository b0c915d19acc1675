"""Baseline kinematic controllers compared with SNAC in the paper's Table I (RNN, SVF) and the
textbook damped-least-squares reference (DLS). Each is registered with
:func:`snac_gym.make_policy` under its short name."""
