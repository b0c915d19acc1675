"""What the QP differential-IK controllers (``pink``, ``mink``) share: the resolved-rate QP, read from the observation.

At every control step both solve, through their library's ``solve_ik`` (QP solver daqp), the
quadratic program of task-based differential IK in the displacement ``Δq = u Δt``:

    min_Δq  ½ ‖J Δq + α ẽ‖²_W + ½ (λ² + ε + μ) ‖Δq‖²
    s.t.    −ū Δt ≤ Δq ≤ ū Δt                                   (VelocityLimit)
            κ (θ⁻ − θ) ≤ Δq ≤ κ (θ⁺ − θ)                         (ConfigurationLimit)

with, in this project's terms,

* ``J`` the task Jacobian (position rows for reach and track, ``[J_v; J_ω]`` for the pose tasks),
  in the base frame, from the library's own kinematics (Pinocchio for pink, MuJoCo for mink);
* ``ẽ = e − ẋ_d/g`` the project's task error ``e`` (the observation's: ``x − x_d``, or
  ``[p − p_d; log₃(R R_dᵀ)]`` for a pose) shifted by the feed-forward of a moving reference, and
  ``α = g Δt`` the libraries' per-step task gain, so that ``α ẽ = Δt (g e − ẋ_d)`` and the task
  term is ``Δt² ‖J u − v‖²`` with the reference velocity ``v = ẋ_d − g e`` of every baseline
  (:func:`snac_gym.baselines._common.reference_velocity`);
* ``W = I`` (the task's cost 1: 1 m of position error weighs as 1 rad of orientation error, as
  the cost's Q = I);
* ``λ² + ε`` the ``damping`` argument of the library's ``solve_ik`` (its Tikhonov term on every
  joint, the same term as a ``DampingTask`` of cost λ, which costs a second task's assembly per
  step), ``λ`` = 0.01 by default (DLS's damping) and ``ε = 10⁻¹²`` the libraries' default ``damping``;
  ``μ = lm_damping ‖α ẽ‖²`` the task's optional Levenberg-Marquardt term (default 0, the libraries'
  default);
* ``ū`` the env's velocity limits, ``θ⁻, θ⁺`` the URDF's position limits (those of
  :class:`~snac_gym.model.kinematics.Kinematics`), ``κ`` the ConfigurationLimit's gain (pink's default 0.5,
  mink's 0.95).

Both constraints are bounds on each joint's Δq, so the feasible set is one box
``max(−ū Δt, κ(θ⁻ − θ)) ≤ Δq ≤ min(ū Δt, κ(θ⁺ − θ))`` (a joint without finite position limits has
only its velocity bound, as the libraries leave it out of their ``ConfigurationLimit``).

Two ways to solve it, the ``assembly`` argument:

* ``"direct"`` (the default): the library's kinematics (mink's ``Configuration.update`` and the site
  Jacobian; for pink, Pinocchio's frame Jacobian in one call, what pink's ``Configuration.update``
  computes in two) and the program above written down here, ``H = JᵀJ + (λ² + ε + μ) I``,
  ``c = α Jᵀẽ``, the box handed to daqp as simple bounds. It is the program the library's
  ``solve_ik`` builds, row for row (``tests/baselines/test_qp_ik.py`` checks the bounds against the
  library's limit rows and the command against ``solve_ik``'s); it skips the library's per-step
  generic assembly in Python (each limit stacking ±I rows, a joint-by-joint limit check, qpsolvers'
  problem and solution objects), which costs 3–5× the solve (docs/qp-ik.md).
* ``"library"``: the library's own ``solve_ik`` end to end, as its users call it.

Without active bounds the minimiser is ``u = Jᵀ(JJᵀ + λ²I)⁻¹ v``: DLS (:mod:`snac_gym.baselines.dls`) with the
same λ. The two differ only in how they stay inside the limits: DLS scales the whole command
into the velocity box (keeping its direction) and has no position limits of its own (on the
7-DOF arms it is clamped into the box Ω(θ) of :mod:`snac_gym.model.joint_limits`); the QP bounds each
joint and lets the others take over the task motion a bounded joint cannot make, and keeps
every joint inside its position limits by construction (a joint closes at most a fraction κ of
its distance to a limit per step).

The task is the project's, not the libraries' ``FrameTask``: a FrameTask's error is the SE(3)
logarithm of the frame's pose relative to its target, in the frame's own axes, whose
translational part couples to the angular velocity through ``Jlog₆`` (a screw motion, not the
straight line of ``ė = J u − ẋ_d``), and it has no feed-forward; with it the QP controllers
would solve a different task than every other controller of the comparison. Each library's
``Task`` base class is subclassed with the project's error and the library's Jacobian, and
everything else (``Configuration``, ``ConfigurationLimit``, ``VelocityLimit``, ``solve_ik`` and its
damping) is the library's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from snac_gym.baselines._common import ObservationReader, clip_to_box

from snac_gym.common.extras import MissingExtraError, install_line, require
from snac_gym.policies.base import BasePolicy, non_negative_float, positive_float

#: The QP solver: daqp, installed by the ``ik`` extra (``qpsolvers[daqp]``).
SOLVER = "daqp"
#: daqp's settings. Its default primal tolerance, 1e-6 on Δq (rad), lets a joint pressed against a
#: position limit cross it by up to 1e-6 rad per step (6.2e-5 rad beyond it after 1500 steps on the Panda
#: sample of tests/baselines/test_qp_ik.py); at 1e-15 the bound holds to the last bit (margin ≥ 0).
SOLVER_SETTINGS = {"primal_tol": 1e-15}
#: The ways to assemble and solve the QP (module docs).
ASSEMBLIES = ("direct", "library")
#: ε, the libraries' default ``damping`` of ``solve_ik`` (kept under λ²: H stays positive definite at λ = 0).
TIKHONOV = 1e-12


def require_library(module: str, name: str) -> Any:
    """Import the IK library ``module`` and check that qpsolvers has daqp; one line naming the extra if not.

    Raises:
        MissingExtraError: If the library, qpsolvers or daqp is not installed.
    """
    library = require(module, "ik", name)
    qpsolvers = require("qpsolvers", "ik", name)
    if SOLVER not in qpsolvers.available_solvers:
        raise MissingExtraError(f"{name} needs the 'ik' extra (qpsolvers with daqp): {install_line('ik')}")
    return library


class QPIKPolicy(BasePolicy):
    """Resolved-rate QP differential IK (module docs); subclasses set up one library.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        gain: Task-space feedback gain ``g``, 1/s; the effort knob (``effort_parameter``), as DLS's
            ``gain``. The library's task gain is ``α = g Δt``, which must be ≤ 1.
        damping: The damping ``λ``, m/rad (DLS's λ): ``solve_ik(damping=λ² + ε)``.
        lm_damping: The task's Levenberg-Marquardt damping (the libraries' ``lm_damping``).
        limit_gain: Gain κ of the library's ``ConfigurationLimit``, in (0, 1]; ``None``: the library's default.
        assembly: ``"direct"`` (the QP written down here from the library's kinematics and solved by
            daqp with the box as bounds) or ``"library"`` (the library's ``solve_ik``); the same QP (module docs).

    Raises:
        MissingExtraError: If the library or daqp is not installed.
        ValueError: If a parameter is out of range.

    Attributes:
        effort_parameter: ``"gain"``, for the evaluator's effort matching.
    """

    effort_parameter = "gain"
    #: The library's module (also its name in messages) and its default ConfigurationLimit gain.
    module = ""
    default_limit_gain = 1.0

    def __init__(
        self,
        env: Any,
        gain: float = 2.0,
        damping: float = 0.01,
        lm_damping: float = 0.0,
        limit_gain: float | None = None,
        assembly: str = "direct",
    ) -> None:
        super().__init__(env)
        library = require_library(self.module, self.module)
        self.gain = positive_float("gain", gain)
        if self.gain * self.dt > 1.0:
            raise ValueError(f"gain·dt must be ≤ 1 (the library's task gain α ∈ [0, 1]), got {self.gain}·{self.dt}")
        self.damping = non_negative_float("damping", damping)
        #: The ``damping`` argument of ``solve_ik``: λ² plus the libraries' default ε.
        self.regularisation = self.damping**2 + TIKHONOV
        self.lm_damping = non_negative_float("lm_damping", lm_damping)
        self.limit_gain = self.default_limit_gain if limit_gain is None else positive_float("limit_gain", limit_gain)
        if self.limit_gain > 1.0:
            raise ValueError(f"limit_gain must be in (0, 1], got {limit_gain}")
        if assembly not in ASSEMBLIES:
            raise ValueError(f"assembly must be one of {', '.join(ASSEMBLIES)}, got {assembly!r}")
        self.assembly = assembly
        self._reader = ObservationReader(self)
        self._q = self._reader.q
        position = getattr(self.kinematics, "position", self.kinematics)  # PoseKinematics wraps the position one
        self._lower = np.asarray(position.lower_limits, dtype=float)
        self._upper = np.asarray(position.upper_limits, dtype=float)
        self.task_dim = self.layout.task_dim
        # The box's constant parts (module docs): the velocity bound ū Δt, and the position limits
        # where both are finite (the libraries' ConfigurationLimit leaves the other joints out).
        self._step_bound = np.asarray(self.velocity_limits, dtype=float) * self.dt
        limited = np.isfinite(self._lower) & np.isfinite(self._upper) & (self._upper > self._lower + 1e-10)
        self._limit_lower = np.where(limited, self._lower, -np.inf)
        self._limit_upper = np.where(limited, self._upper, np.inf)
        self._no_rows = np.zeros((0, len(self._lower)))
        self._sense = np.zeros(len(self._lower), dtype=np.intc)
        # The per-step arithmetic's constants, folded once: it runs at every control step, where each
        # small-array NumPy operation costs about a microsecond (docs/qp-ik.md, act latency).
        self._regularisation_eye = self.regularisation * np.eye(len(self._lower))
        self._scaled_limit_lower = self.limit_gain * self._limit_lower
        self._scaled_limit_upper = self.limit_gain * self._limit_upper
        self._negative_step_bound = -self._step_bound
        self._inverse_gain = 1.0 / self.gain
        self._rate = 1.0 / self.dt
        self._daqp = require("daqp", "ik", self.module) if assembly == "direct" else None
        self._setup(library, position)

    def _setup(self, library: Any, kinematics: Any) -> None:  # pragma: no cover - abstract
        """Build the library's model, configuration, tasks and limits."""
        raise NotImplementedError

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """The task Jacobian ``J`` at ``q`` from the library's kinematics (its ``Configuration.update``, then the
        task's)."""
        self._configuration.update(q)
        return self._task.compute_jacobian(self._configuration)

    def box(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bounds ``(lower, upper)`` on Δq (rad) at ``q``: both limits together (module docs)."""
        scaled_q = self.limit_gain * q
        lower = np.maximum(self._negative_step_bound, self._scaled_limit_lower - scaled_q)
        upper = np.minimum(self._step_bound, self._scaled_limit_upper - scaled_q)
        return lower, upper

    def _solve(self, q: np.ndarray, error: np.ndarray) -> np.ndarray:
        """``u`` (rad/s) at ``q`` for the task error ``ẽ``, by :attr:`assembly` (module docs; ``_setup``
        gives the library's configuration, task, limits and ``solve_ik``)."""
        if self.assembly == "direct":
            jacobian = self.task_jacobian(q)
            scaled_error = self._task.gain * error  # α ẽ
            hessian = jacobian.T @ jacobian + self._regularisation_eye
            if self.lm_damping:
                hessian.flat[:: len(hessian) + 1] += self.lm_damping * (scaled_error @ scaled_error)
            lower, upper = self.box(q)
            step, _, status, _ = self._daqp.solve(
                hessian, scaled_error @ jacobian, self._no_rows, upper, lower, self._sense, **SOLVER_SETTINGS
            )
            if status <= 0:  # the box always holds Δq = 0, so this is the solver failing, not the problem
                raise RuntimeError(f"{self.module}: daqp found no solution (exit flag {status}) at q={q.tolist()}")
            return step * self._rate
        self._configuration.update(q)
        self._task.error = error
        return self._solve_ik(
            self._configuration,
            self._tasks,
            self.dt,
            solver=SOLVER,
            damping=self.regularisation,
            limits=self._limits,
            **SOLVER_SETTINGS,
        )

    def task_error(self, obs: np.ndarray) -> np.ndarray:
        """``ẽ = e − ẋ_d/g`` of one observation (module docs)."""
        return obs[self._reader.e] - self._inverse_gain * obs[self._reader.xdot_d]

    def measured_q(self, obs: np.ndarray) -> np.ndarray:
        """θ of ``obs``, read at the limit where it is outside its position limits (pink refuses such a
        configuration, mink warns; the QP then allows no further motion outwards)."""
        return np.minimum(np.maximum(obs[self._q], self._lower), self._upper)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``, inside the velocity and position limits."""
        obs = self._reader.read(obs)
        command = self._solve(self.measured_q(obs), self.task_error(obs))
        return clip_to_box(command, self.velocity_limits)  # the solver's tolerance, never more

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` episodes (nothing to set: the controller has no state)."""
        self.internals = {}

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)``: one QP per row, row i is :meth:`act` of row i (one library workspace for all)."""
        obs_batch = self._reader.read_batch(obs_batch)
        return np.array([self.act(obs) for obs in obs_batch], dtype=float).reshape(len(obs_batch), -1)
