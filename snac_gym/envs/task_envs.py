"""The env classes of the paper's tasks and of the opt-in pose tasks, one per task, over :class:`URTaskEnv`.

Their docstrings are the Gymnasium-style reference of each id family (docs/environments.md links them);
:func:`task_env_class` picks a task's class (a task registered later runs in :class:`URTaskEnv` itself).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, cast

from snac_gym.envs.core import JOINT_LIMIT_MARGIN, SHAPED_REWARD, URTaskEnv  # noqa: F401  (the docstrings' :data: links)
from snac_gym.tasks import Task, get_task
from snac_gym.tasks.pose import POSE_TASKS

# The paper's two classes write out what they share (action space, rewards, arguments), as Gymnasium's
# MuJoCo envs do: ``help(ReachEnv)`` and ``help(EllipseTrackEnv)`` are each complete on their own; the
# opt-in pose classes refer to them. The bodies are one line: the task.


class ReachEnv(URTaskEnv):
    """``snac_gym/<Robot>Reach-v1`` (RL-ready) and ``-v0`` (physical units): optimal regulation, reach a fixed target
    point (Section III).

    ## Description
    An arm under joint-velocity control (``ẋ = J u``, eq. 3), simulated in PyBullet (or MuJoCo,
    ``physics="mujoco"``, or on the exact kinematic model, ``physics="kinematic"``). The end effector must reach a fixed
    target x_d and stay there (x_d constant, ẋ_d = 0). One id per registered robot:
    ``snac_gym/UR10Reach-v0`` (the paper's arm), ``UR5Reach-v0``, ``UR3Reach-v0``,
    ``PandaReach-v0``, ``XArm7Reach-v0``; the id fixes ``robot``.

    ## Action Space
    ``action_type="velocity"`` (the -v0 default): ``Box(-v_max, v_max, (m,), float64)``, the commanded
    joint velocities u = θ̇ in rad/s of the m joints, applied by PyBullet ``VELOCITY_CONTROL``
    motors (each bounded by its URDF effort) and held for one control period ``dt``. ``v_max``
    are the URDF limits (UR10: 2.16, 2.16, 3.15, 3.2, 3.2, 3.2 rad/s).
    ``action_type="normalized"`` (the -v1 default, for learners): ``Box(-1, 1, (m,), float32)``, the
    command is u = a·v_max per joint (a = u / v_max; ``make_policy`` maps a controller's u to it). An action outside the
    box is **clipped** to it (``info["command"]`` holds the applied u in rad/s); an action with NaN/inf or of the wrong
    shape raises ``ValueError``.

    ## Observation Space
    ``Box(low, high, (2m + 15,), observation_dtype)`` (UR10: 27 values), float64 by default on -v0,
    float32 on -v1 and with ``observation_dtype=np.float32`` (the float64 values rounded). Positions are in
    the robot's base frame (for a UR arm the frame the pendant shows). Bounds: ±inf on -v0
    (the space of the real-robot env); with ``finite_observation_bounds=True``
    (``env.unwrapped.observation_bounds()``): θ within the URDF joint limits widened by
    :data:`JOINT_LIMIT_MARGIN` (the simulator's joint-limit constraint is soft; ±2π for a joint
    without limits); positions within ±ρ per axis, ρ the sum of the arm's link offsets (UR10: 1.88 m;
    a pose task's rotation vectors within ±π); ẋ_d within ±3 m/s; e within ±2ρ. θ̇ stays unbounded
    there: the joint-limit constraint can push the measured velocity past the motor limits.
    ``finite_observation_bounds="clip"`` (the -v1 default) bounds θ̇ by ±v_max too and clips every
    observation into the bounds (in float64, before the cast), so it always lies in the space.

    | Index (UR10) | Observation                                    | Unit  |
    |--------------|------------------------------------------------|-------|
    | 0–5          | joint positions θ                              | rad   |
    | 6–11         | joint velocities θ̇ (measured)                 | rad/s |
    | 12–14        | end-effector position x = f(θ)                 | m     |
    | 15–17        | target x_d                                     | m     |
    | 18–20        | desired velocity ẋ_d (zero)                    | m/s   |
    | 21–23        | error e = x − x_d (eq. 4)                      | m     |
    | 24–26        | reference centre x_c: the target               | m     |

    ``env.unwrapped.obs_layout.unpack(obs)`` returns these as named fields.

    ## Rewards
    ``reward_type="dense"`` (default): ``−(eₖᵀQeₖ + uₖᵀRuₖ)``, the negative of the paper's
    instantaneous cost (eq. 6) with eₖ the error at the start of the step and uₖ the applied
    command, Q = I₃, R = I by default; so ``−Σ reward·dt`` is the error and effort part of the
    evaluator's trajectory cost. ``reward_type="sparse"``: 0 when ``is_success`` after the step,
    −1 otherwise. ``reward_type="shaped"`` (for learners, the reward PPO trains on), with
    d = ‖e‖ after the step and a = u / v_max: ``r = −10·d + exp(−(d / 0.01)²) − 0.01·‖a‖²``
    (:data:`SHAPED_REWARD`). ``reward_type="cost"``: minus the step's share of the evaluator's
    trajectory cost under ``cost`` (a :class:`~snac_gym.control.cost.CostConvention`, default the paper's
    Table I cost), ``−Δt (eₖᵀQeₖ + uₖᵀRuₖ [+ u̇ₖᵀRu̇ₖ])``, so the return is −V exactly
    (``tests/envs/test_core_cost_reward.py``); its Q = q_scale·I and R = I are the env's. ``info`` carries ``error`` (after the
    step), ``error_norm``, ``cost_error``, ``cost_effort``, ``cost_smoothness`` (u̇ᵀRu̇, u̇ = (uₖ − uₖ₋₁)/dt, u₋₁ = 0),
    ``command``, ``t`` and ``is_success`` (‖e‖ ≤ ``success_tolerance``, default 1 mm).

    ## Starting State
    ``reset(seed=None, options=None)``: with no options, a random seed pose (end effector in the
    sample cuboid, away from singularities and joint limits) and a random target in the cuboid,
    drawn from ``self.np_random``. ``options`` pins them exactly, to replay any run:
    ``q0`` (start joint positions, rad; missing: random) and ``target`` (3 numbers, m; missing
    when options are given: the paper's target [-0.658, 0.626, 0.407] m). Unknown keys raise
    ``ValueError``; a target outside the reachable workspace raises a ``ValueError`` naming it.
    Every reset restores the simulator state saved after loading, then poses the joints at rest.

    ## Episode End
    Termination on success only with ``terminate_on_success=True``. Truncation by the
    registration's ``TimeLimit`` after ``max_episode_steps`` control steps (default 1000, i.e.
    8 s at 125 Hz): ``gym.make(id, max_episode_steps=N)`` sets it and
    ``env.spec.max_episode_steps`` shows it.

    ## Arguments
    ``gym.make("snac_gym/UR10Reach-v0", **kwargs)``; unknown arguments raise ``TypeError``.

    | argument               | default        | meaning                                            |
    |------------------------|----------------|----------------------------------------------------|
    | ``robot``              | the id's       | fixed by the id; another robot raises ``ValueError`` naming its id |
    | ``physics``            | ``"pybullet"`` | ``"pybullet"`` (velocity motors), ``"mujoco"`` (the same URDF in MuJoCo, velocity servos; the ``mujoco`` extra) or ``"kinematic"`` (θₖ₊₁ = θₖ + uₖΔt exactly, θ̇ the held command; no rendering) |
    | ``pybullet_solver``    | -v0 ``"pgs"``, -v1 ``"dantzig"`` | how PyBullet solves its motors: ``"pgs"`` (its iterated default; under gravity each joint lags its command a little, docs/physics.md) or ``"dantzig"`` (solved directly: θ̇ = u wherever the motor is within its force bound); the other engines ignore it |
    | ``dt``                 | ``1/125``      | control period, s, in (0, 1]                       |
    | ``n_substeps``         | ``3``          | physics steps per control period                   |
    | ``action_type``        | -v0 ``"velocity"``, -v1 ``"normalized"`` | ``"velocity"`` (rad/s) or ``"normalized"`` ([−1, 1]) |
    | ``observation_dtype``  | -v0 ``np.float64``, -v1 ``"float32"`` | ``np.float64`` or ``np.float32``      |
    | ``finite_observation_bounds`` | -v0 ``False``, -v1 ``"clip"`` | ``False`` (±inf), ``True`` (physical bounds, θ̇ unbounded) or ``"clip"`` (every field bounded, the observation clipped into them) |
    | ``reward_type``        | ``"dense"``    | ``"dense"``, ``"sparse"``, ``"shaped"``, ``"cost"``|
    | ``cost``               | ``None``       | the ``CostConvention`` of ``reward_type="cost"``   |
    | ``Q``, ``R``           | identity       | cost weights (matrix or diagonal)                  |
    | ``success_tolerance``  | ``1e-3``       | success threshold on the error norm, m             |
    | ``terminate_on_success`` | ``False``    | end the episode on success                         |
    | ``sample_space``       | the robot's cuboid | a :class:`~snac_gym.sampling.SampleSpace`      |
    | ``render_mode``        | ``None``       | ``"rgb_array"`` (headless) or ``"human"`` (PyBullet's GUI; without a display, or with MuJoCo, it shows nothing and warns on the first step) |
    | ``render_width``, ``render_height`` | 480 | image size for ``"rgb_array"``, 1–8192 pixels |
    | ``render_distance``, ``render_yaw``, ``render_pitch``, ``render_target_position`` | fitted | the camera as panda-gym sets it (m, degrees as PyBullet's ``computeViewMatrixFromYawPitchRoll``, pitch in [−89, 89], negative looks down; world frame); each one not given is fitted so that the arm, its start poses and the cuboid fill the frame |
    | ``render_every``       | 25 images/s    | control steps between two new images; ``render_fps`` is 1/dt |
    | ``max_steps``          | ``None``       | the env truncates itself after N steps (a constructed env, the vector env); under ``gym.make`` deprecated: use ``max_episode_steps`` |
    | ``backend``            | ``None``       | deprecated name of ``physics``                     |

    ## Version History
    * v0 (snac-gym 0.1.0): initial version.
    * v0 (unreleased, same numbers): one id per robot; ``robot=`` naming another robot than the
      id's is refused; ``physics=`` names the arm's model (``backend=`` is its deprecated alias);
      ``gym.make(id, max_steps=N)`` is deprecated for ``max_episode_steps=N`` and no longer
      lengthens the ``TimeLimit``.
    * v1 (unreleased): RL-ready defaults, the same env otherwise: ``action_type="normalized"``,
      ``observation_dtype="float32"``, ``finite_observation_bounds="clip"``, ``pybullet_solver="dantzig"``
      (PyBullet's motors follow their commands without v0's lag under gravity). v0 keeps physical units
      (rad/s, float64, ±inf bounds) and PyBullet's iterated motor solve, and stays registered.
    """  # noqa: E501

    task_spec = get_task("reach")


class EllipseTrackEnv(URTaskEnv):
    """``snac_gym/<Robot>EllipseTrack-v1`` (RL-ready) and ``-v0`` (physical units): optimal tracking of a point moving
    on an ellipse (Section IV).

    ## Description
    An arm under joint-velocity control (``ẋ = J u``, eq. 3), simulated in PyBullet (or MuJoCo,
    ``physics="mujoco"``, or on the exact kinematic model, ``physics="kinematic"``). The end effector must follow x_d(t)
    moving on an ellipse (centre, semi-axes, plane orientation, angular speed, phase), with ẋ_d(t)
    known; see :class:`~snac_gym.references.Ellipse`. One id per registered robot:
    ``snac_gym/UR10EllipseTrack-v0`` (the paper's arm), ``UR5EllipseTrack-v0``,
    ``UR3EllipseTrack-v0``, ``PandaEllipseTrack-v0``, ``XArm7EllipseTrack-v0``; the id fixes ``robot``.

    ## Action Space
    ``action_type="velocity"`` (the -v0 default): ``Box(-v_max, v_max, (m,), float64)``, the commanded
    joint velocities u = θ̇ in rad/s of the m joints, applied by PyBullet ``VELOCITY_CONTROL``
    motors and held for one control period ``dt``; ``v_max`` are the URDF limits (UR10: 2.16,
    2.16, 3.15, 3.2, 3.2, 3.2 rad/s). ``action_type="normalized"`` (the -v1 default):
    ``Box(-1, 1, (m,), float32)``, u = a·v_max. An action outside the box is **clipped** (``info["command"]`` holds the
    applied u); NaN/inf or a wrong shape raises ``ValueError``.

    ## Observation Space
    ``Box(low, high, (2m + 15,), observation_dtype)`` (UR10: 27 values), float64 (-v0) or
    float32 (-v1), positions in the robot's base frame; bounds ±inf (-v0), or with
    ``finite_observation_bounds=True`` or ``"clip"`` (-v1) those of :class:`ReachEnv` (ẋ_d within
    ±3 m/s, the fastest ellipse :class:`~snac_gym.references.Ellipse` accepts).

    | Index (UR10) | Observation                                    | Unit  |
    |--------------|------------------------------------------------|-------|
    | 0–5          | joint positions θ                              | rad   |
    | 6–11         | joint velocities θ̇ (measured)                 | rad/s |
    | 12–14        | end-effector position x = f(θ)                 | m     |
    | 15–17        | desired position x_d(t)                        | m     |
    | 18–20        | desired velocity ẋ_d(t)                        | m/s   |
    | 21–23        | error e = x − x_d (eq. 4)                      | m     |
    | 24–26        | the ellipse centre x_c (x_d − x_c gives φ(0) = 0, eq. 29) | m |

    ## Rewards
    As :class:`ReachEnv`: ``"dense"`` (default) ``−(eₖᵀQeₖ + uₖᵀRuₖ)`` (eq. 6), ``"sparse"``
    0/−1 on ``is_success``, ``"shaped"`` ``−10·d + exp(−(d / 0.01)²) − 0.01·‖u/v_max‖²``.
    ``info`` carries ``error``, ``error_norm``, ``cost_error``, ``cost_effort``,
    ``cost_smoothness``, ``command``, ``t`` and ``is_success`` (‖e‖ ≤ ``success_tolerance``,
    default 5 mm).

    ## Starting State
    ``reset(seed=None, options=None)``: with no options, a random seed pose and a random feasible
    ellipse (wholly reachable, checked with the kinematics), drawn from ``self.np_random``.
    ``options`` pins them: ``q0`` (rad) and ``ellipse`` (a dict with ``centre``, ``semi_axes``
    or ``radius``, ``orientation``, ``angular_speed``, ``phase``; missing when options are given:
    the paper's circle, radius 0.2 m around [-0.7, 0, 0.5] m in the horizontal plane, 0.075 rad/s).
    Unknown keys or an unreachable ellipse raise ``ValueError``.

    ## Episode End
    Tracking never terminates; it only truncates, by the registration's ``TimeLimit`` after
    ``max_episode_steps`` control steps (default 2500, i.e. 20 s at 125 Hz).

    ## Arguments
    ``gym.make("snac_gym/UR10EllipseTrack-v0", **kwargs)``: the arguments of :class:`ReachEnv`
    (``robot`` fixed by the id, ``physics``, ``pybullet_solver``, ``dt``, ``n_substeps``, ``action_type``,
    ``observation_dtype``, ``finite_observation_bounds``, ``reward_type``, ``Q``, ``R``,
    ``sample_space``, ``render_mode``, ``render_width``, ``render_height``, ``render_every``,
    ``max_steps``), with ``success_tolerance`` 5e-3 m by default; ``terminate_on_success`` has no
    effect. Unknown arguments raise ``TypeError``.

    ## Version History
    * v0 (snac-gym 0.1.0): initial version.
    * v0 (unreleased, same numbers): one id per robot; ``robot=`` naming another robot than the
      id's is refused; ``physics=`` names the arm's model (``backend=`` is its deprecated alias);
      ``gym.make(id, max_steps=N)`` is deprecated for ``max_episode_steps=N`` and no longer
      lengthens the ``TimeLimit``.
    * v1 (unreleased): RL-ready defaults, the same env otherwise: ``action_type="normalized"``,
      ``observation_dtype="float32"``, ``finite_observation_bounds="clip"``, ``pybullet_solver="dantzig"``
      (PyBullet's motors follow their commands without v0's lag under gravity). v0 keeps physical units
      (rad/s, float64, ±inf bounds) and PyBullet's iterated motor solve, and stays registered.
    """

    task_spec = get_task("track")


class PoseReachEnv(URTaskEnv):
    """``snac_gym/<Robot>PoseReach-v0``: regulation of the full end-effector pose (opt-in).

    ## Description
    The end-effector frame must reach a fixed pose, position and orientation:
    e = [p − p_d; log₃(R R_dᵀ)] → 0 (:mod:`snac_gym.tasks.pose`). The ids exist once
    :func:`snac_gym.envs.register_pose_envs` ran: ``snac_gym/UR10PoseReach-v0``,
    ``PandaPoseReach-v0``, ... (one per registered robot; the 7-DOF arms are redundant for it).

    ## Action Space
    As :class:`ReachEnv`: joint velocities in rad/s (or normalized), clipped to the URDF limits.

    ## Observation Space
    ``Box(low, high, (2m + 30,))``: θ, θ̇ (m values each), then x = [p; log₃ R], x_d, ẋ_d
    (zero), e and the target pose [p_d; log₃ R_d] (6 values each; m and rad, base frame).

    ## Rewards
    As :class:`ReachEnv`, with Q = I₆ by default: 1 mrad of orientation error costs as much as
    1 mm of position error. ``is_success``: ‖e‖ ≤ ``success_tolerance``, default 1e-3 (m and rad).

    ## Starting State
    With no options, a random seed pose and the pose of a random well-conditioned configuration
    with its tool in the cuboid. ``options``: ``q0`` and ``pose``
    (``{'position': [3 numbers, m], 'rotation': [3 numbers, rotation vector, rad]}``).

    ## Episode End
    Termination on success only with ``terminate_on_success=True``; truncation after
    ``max_episode_steps`` (default 1500).

    ## Arguments
    Those of :class:`ReachEnv`.

    ## Version History
    * v0 (snac-gym 0.1.0): initial version, as ``snac_gym/PoseReach-v0`` with ``robot=``.
    * v0 (unreleased, same numbers): one id per robot (``snac_gym/UR10PoseReach-v0``, ...); with
      ``finite_observation_bounds=True`` the rotation vectors are bounded by ±π (they were by the reach ρ).
    * v1 (unreleased): the RL-ready defaults of :class:`ReachEnv`'s v1.
    """

    task_spec = POSE_TASKS[0]


class PoseEllipseTrackEnv(URTaskEnv):
    """``snac_gym/<Robot>PoseEllipseTrack-v0``: an ellipse for the position at a fixed orientation (opt-in).

    ## Description
    The end-effector frame must follow p_d(t) on an ellipse with its orientation R_d fixed
    (:mod:`snac_gym.tasks.pose`). The ids exist once
    :func:`snac_gym.envs.register_pose_envs` ran: ``snac_gym/UR10PoseEllipseTrack-v0``,
    ``PandaPoseEllipseTrack-v0``, ... (one per registered robot).

    ## Action Space
    As :class:`ReachEnv`: joint velocities in rad/s (or normalized), clipped to the URDF limits.

    ## Observation Space
    As :class:`PoseReachEnv`; the centre field holds [ellipse centre; log₃ R_d].

    ## Rewards
    As :class:`PoseReachEnv`; ``is_success``: ‖e‖ ≤ ``success_tolerance``, default 5e-3.

    ## Starting State
    With no options, a random seed pose and a feasible random ellipse of the cuboid at the
    orientation of a random seed pose. ``options``: ``q0`` and ``pose_ellipse`` (the ellipse keys
    of :class:`EllipseTrackEnv` plus ``rotation``, rad).

    ## Episode End
    Tracking never terminates; truncation after ``max_episode_steps`` (default 2500).

    ## Arguments
    Those of :class:`ReachEnv`.

    ## Version History
    * v0 (snac-gym 0.1.0): initial version, as ``snac_gym/PoseEllipseTrack-v0`` with ``robot=``.
    * v0 (unreleased, same numbers): one id per robot (``snac_gym/UR10PoseEllipseTrack-v0``, ...); with
      ``finite_observation_bounds=True`` the rotation vectors are bounded by ±π (they were by the reach ρ).
    * v1 (unreleased): the RL-ready defaults of :class:`ReachEnv`'s v1.
    """

    task_spec = POSE_TASKS[1]


#: The env class of each task that has its own (the others run in :class:`URTaskEnv` with ``task=``).
TASK_ENV_CLASSES: Mapping[str, type[URTaskEnv]] = MappingProxyType(
    {cls.task_spec.name: cls for cls in (ReachEnv, EllipseTrackEnv, PoseReachEnv, PoseEllipseTrackEnv)}
)

#: Deprecated names of :class:`ReachEnv` and :class:`EllipseTrackEnv` (snac-gym 0.1.0): the
#: classes serve every robot, the UR10 is only their default.
UR10ReachEnv = ReachEnv
UR10EllipseTrackEnv = EllipseTrackEnv


def task_env_class(task: Task[Any] | str) -> type[URTaskEnv]:
    """The env class of ``task``: its own (:data:`TASK_ENV_CLASSES`) or :class:`URTaskEnv`.

    A task registered later (docs/extending.md) has no class of its own: :class:`URTaskEnv`
    runs it, given ``task=<its name>`` (its registered ids pass that).
    """
    task = cast("Task[Any]", get_task(task))  # a registered task (get_task returns Any)
    own = TASK_ENV_CLASSES.get(task.name)
    return own if own is not None and own.task_spec is task else URTaskEnv
