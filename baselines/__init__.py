"""Baseline kinematic controllers compared with SNAC in the paper's Table I (RNN, SVF) and the
textbook damped-least-squares reference (DLS). Each is registered with
:func:`snac_gym.make_policy` under its short name.

* ``rnn`` — :class:`baselines.rnn.RNNPolicy`: the dual recurrent neural network of Li, Zhang
  and Jin (IEEE TNNLS 2017), ``ε λ̇ = ẋ_d + k(x_d − x) − J P_Ω(Jᵀλ)``, ``u = P_Ω(Jᵀλ)``.
* ``svf`` — :class:`baselines.svf.SVFPolicy`: closed-loop IK with Colomé and Torras'
  singular-value-filtered inverse (IROS 2012), ``u = Ĵ⁺(ẋ_d + K(x_d − x))``.
* ``dls`` — :class:`baselines.dls.DLSPolicy`: damped least squares,
  ``u = Jᵀ(JJᵀ + λ²I)⁻¹(ẋ_d + K(x_d − x))``.
* ``pink``, ``mink`` — :class:`baselines.pink_ik.PinkPolicy`, :class:`baselines.mink_ik.MinkPolicy`:
  QP differential IK through the pink (Pinocchio) and mink (MuJoCo) libraries, joint position and
  velocity limits as QP constraints (:mod:`baselines.qp_ik`; the ``ik`` extra).

All take the Jacobian from the env's shared kinematics (pink and mink from their library's model
of the same URDF and frames), keep every command inside the
joint-velocity limits and name their effort knob in the class attribute
``effort_parameter`` (``"gain"`` for all of them). Equations, assumptions, default gains and
measured figures: ``docs/baselines.md`` (``docs/qp-ik.md`` for pink and mink)."""
