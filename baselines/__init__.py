"""Baseline kinematic controllers compared with SNAC in the paper's Table I (RNN, SVF) and the
textbook damped-least-squares reference (DLS). Each is registered with
:func:`snac_gym.make_policy` under its short name.

* ``rnn`` — :class:`baselines.rnn.RNNPolicy`: the dual recurrent neural network of Li, Zhang
  and Jin (IEEE TNNLS 2017), ``ε λ̇ = ẋ_d + k(x_d − x) − J P_Ω(Jᵀλ)``, ``u = P_Ω(Jᵀλ)``.
* ``svf`` — :class:`baselines.svf.SVFPolicy`: closed-loop IK with Colomé and Torras'
  singular-value-filtered inverse (IROS 2012), ``u = Ĵ⁺(ẋ_d + K(x_d − x))``.
* ``dls`` — :class:`baselines.dls.DLSPolicy`: damped least squares,
  ``u = Jᵀ(JJᵀ + λ²I)⁻¹(ẋ_d + K(x_d − x))``.

All take the Jacobian from the env's shared kinematics, keep every command inside the
joint-velocity limits and name their effort knob in the class attribute
``effort_parameter`` (``"gain"`` for all three). Equations, assumptions, default gains and
measured figures: ``docs/baselines.md``."""
