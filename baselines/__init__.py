"""Baseline kinematic controllers compared with SNAC in the paper's Table I (RNN, SVF) and the
textbook damped-least-squares reference (DLS). Each is registered with
:func:`snac_gym.make_policy` under its short name.

* ``rnn`` — :class:`snac_gym.baselines.rnn.RNNPolicy`: the dual recurrent neural network of Li, Zhang
  and Jin (IEEE TNNLS 2017), ``ε λ̇ = ẋ_d + k(x_d − x) − J P_Ω(Jᵀλ)``, ``u = P_Ω(Jᵀλ)``.
* ``svf`` — :class:`snac_gym.baselines.svf.SVFPolicy`: closed-loop IK with Colomé and Torras'
  singular-value-filtered inverse (IROS 2012), ``u = Ĵ⁺(ẋ_d + K(x_d − x))``.
* ``dls`` — :class:`snac_gym.baselines.dls.DLSPolicy`: damped least squares,
  ``u = Jᵀ(JJᵀ + λ²I)⁻¹(ẋ_d + K(x_d − x))``.
* ``pink``, ``mink`` — :class:`snac_gym.baselines.pink_ik.PinkPolicy`, :class:`snac_gym.baselines.mink_ik.MinkPolicy`:
  QP differential IK through the pink (Pinocchio) and mink (MuJoCo) libraries, joint position and
  velocity limits as QP constraints (:mod:`snac_gym.baselines.qp_ik`; the ``ik`` extra).

All take the Jacobian from the env's shared kinematics (pink and mink from their library's model
of the same URDF and frames), keep every command inside the
joint-velocity limits and name their effort knob in the class attribute
``effort_parameter`` (``"gain"`` for all of them). Equations, assumptions, default gains and
measured figures: ``docs/baselines.md`` (``docs/qp-ik.md`` for pink and mink)."""

if __name__ == "baselines":  # this folder imported as a top-level package (from the repository's root, or an old import)
    raise ImportError(
        "snac-gym's baselines package is imported as snac_gym.baselines since 0.2.0 "
        "(`from snac_gym.baselines import ...`); the top-level name `baselines` is no longer installed"
    )
