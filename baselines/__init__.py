"""Baseline kinematic controllers compared with SNAC: the paper's Table I (RNN, SVF), the textbook
damped-least-squares reference (DLS), the optimal-control ones (LQR, MPC) and QP differential IK. Each is
registered with :func:`snac_gym.make_policy` under its short name. This folder installs as
``snac_gym.baselines``.

* ``rnn`` — :class:`snac_gym.baselines.rnn.RNNPolicy`: the dual recurrent neural network of Li, Zhang
  and Jin (IEEE TNNLS 2017), ``ε λ̇ = ẋ_d + k(x_d − x) − J P_Ω(Jᵀλ)``, ``u = P_Ω(Jᵀλ)``.
* ``svf`` — :class:`snac_gym.baselines.svf.SVFPolicy`: closed-loop IK with Colomé and Torras'
  singular-value-filtered inverse (IROS 2012), ``u = Ĵ⁺(ẋ_d + K(x_d − x))``.
* ``dls`` — :class:`snac_gym.baselines.dls.DLSPolicy`: damped least squares,
  ``u = Jᵀ(JJᵀ + λ²I)⁻¹(ẋ_d + K(x_d − x))``.
* ``lqr`` — :class:`snac_gym.baselines.lqr.LQRPolicy`: the infinite-horizon LQR of ``ė = J u`` at the
  Jacobian frozen at the current θ (closed form, :mod:`snac_gym.control.optimality`), for the paper's cost.
* ``mpc`` — :class:`snac_gym.baselines.mpc.MPCPolicy`: receding-horizon Gauss-Newton on the evaluator's
  trajectory cost, the limits as barrier constraints (the trajectory optimiser, :mod:`snac_gym.control.trajopt`).
* ``pink``, ``mink`` — :class:`snac_gym.baselines.pink_ik.PinkPolicy`, :class:`snac_gym.baselines.mink_ik.MinkPolicy`:
  QP differential IK through the pink (Pinocchio) and mink (MuJoCo) libraries, joint position and
  velocity limits as QP constraints (:mod:`snac_gym.baselines.qp_ik`; the ``ik`` extra).

All take the Jacobian from the env's shared kinematics (pink and mink from their library's model
of the same URDF and frames), keep every command inside the
joint-velocity limits and name their effort knob in the class attribute
``effort_parameter`` (``"gain"``; ``"q_scale"`` for lqr and mpc). Equations, assumptions, default gains and
measured figures: ``docs/baselines.md`` (``docs/qp-ik.md`` for pink and mink)."""

if (
    __name__ == "baselines"
):  # this folder imported as a top-level package (from the repository's root, or an old import)
    raise ImportError(
        "snac-gym's baselines package is imported as snac_gym.baselines since 0.2.0 "
        "(`from snac_gym.baselines import ...`); the top-level name `baselines` is no longer installed"
    )
