"""A batched vector env: N episodes of the kinematic model stepped at once, in NumPy.

``gym.make_vec("snac_gym/UR10Reach-v0", num_envs=N, vectorization_mode="vector_entry_point")``
(and the same for every registered task) returns a :class:`URTaskVectorEnv`. It is the single
env with ``physics="kinematic"`` (θₖ₊₁ = θₖ + uₖΔt exactly, θ̇ the held command; the evaluator's
engine) run N times in lockstep: the same arguments, spaces, rewards, infos and episode ends,
but one array operation per quantity per step instead of N Python calls.

Episode for episode it matches ``gym.make_vec(id, N, vectorization_mode="sync",
physics="kinematic")``, i.e. a :class:`gymnasium.vector.SyncVectorEnv` of single kinematic envs
(tests/envs/test_vector.py): ``reset(seed=s)`` seeds sub-env i with ``s + i``, each sub-env draws
its episodes from its own generator with the single env's code (:func:`~snac_gym.envs.core.draw_episode`),
and autoreset follows Gymnasium's default ``AutoresetMode.NEXT_STEP``: the step after an episode
ends returns that sub-env's reset observation and reset info, reward 0 and no termination or
truncation, and ignores its action. Values agree to rounding (≤ 1e-12), not bit for bit: the
single env evaluates f(θ) with Pinocchio and the reference with scalar ``math`` calls, this env
with :class:`~snac_gym.model.kinematics.PositionChain` and NumPy's vectorised ``cos``/``sin``.

Speed comes from keeping everything per step in arrays: forward kinematics of positions only
(:class:`PositionChain`, no Jacobian), references as stacked ellipse parameters
(:class:`ReferenceBatch`), costs and rewards as row sums. Resets stay per sub-env (they run the
single env's rejection sampling and IK), once per episode.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from snac_gym.common.validation import whole_number
from snac_gym.control.cost import step_costs
from snac_gym.envs.core import URTaskEnv, draw_episode, physics_argument, shaped_reward
from snac_gym.envs.ids import IdRobotCheck
from snac_gym.envs.reference_batch import ReferenceBatch
from snac_gym.envs.task_envs import task_env_class
from snac_gym.envs.vector_autoreset import merge_reset_infos, reset_mask, seed_list
from snac_gym.model.kinematics import Kinematics, PositionChain, joint_step
from snac_gym.references import Reference
from snac_gym.tasks import Task, get_task

__all__ = [
    "MAX_NUM_ENVS",
    "EllipseTrackVectorEnv",
    "KinematicEpisodes",
    "ReachVectorEnv",
    "ReferenceBatch",
    "URTaskVectorEnv",
    "task_vector_env_class",
    "vector_env_supports",
]


#: The most episodes one vector env steps (2**20: about 3.3 GB of state at 3.2 kB each; the benchmarks use 4096).
MAX_NUM_ENVS = 1 << 20


class KinematicEpisodes:
    """The state of N kinematic episodes and their batched step; the engine of both vector envs.

    Holds what the single kinematic env holds per episode (θ, θ̇, step count, last command,
    reference, random generator) as arrays, and the single env ``template`` built from the same
    arguments (it checked them and gives the kinematics, weights, limits and spaces).

    Args:
        template: A single env with ``physics="kinematic"``.
        count: Number of episodes N.
        horizon: Episode length in control steps (truncation).
    """

    def __init__(self, template: URTaskEnv, count: int, horizon: int) -> None:
        self.template = template
        kinematics = template.kinematics
        self.count, self.horizon, self.dt = count, int(horizon), float(template.dt)
        m, n = kinematics.n_joints, kinematics.task_dim
        self.layout = template.obs_layout
        self.chain = PositionChain.from_kinematics(kinematics)
        self.limits = template.velocity_limits.copy()
        self.q = np.zeros((count, m))
        self.qdot = np.zeros((count, m))
        self.last_command = np.zeros((count, m))
        self.steps = np.zeros(count, dtype=np.int64)
        self.x = np.zeros((count, n))
        self.x_d = np.zeros((count, n))
        self.xdot_d = np.zeros((count, n))
        self.error = np.zeros((count, n))
        self.references = ReferenceBatch(count, n)
        self.generators: list[np.random.Generator | None] = [None] * count

    # -- resets ----------------------------------------------------------------------------------
    def reset(
        self, indices: Sequence[int] | np.ndarray, seeds: Sequence[int | None], options: Mapping[str, Any] | None
    ) -> list[dict[str, Any]]:
        """Start a new episode in each of ``indices`` (seeding its generator when a seed is given).

        Returns:
            The single env's reset info of each, in order.
        """
        template = self.template
        q0s = []
        for index, seed in zip(indices, seeds, strict=True):
            if seed is not None or self.generators[index] is None:
                self.generators[index] = seeding.np_random(seed)[0]
            q0, reference = draw_episode(  # the episode's generator: set just above when it was None
                template.task,
                template.kinematics,
                cast(np.random.Generator, self.generators[index]),
                template.sample_space,
                options,
            )
            self.q[index] = q0
            self.references.set(index, reference)
            q0s.append(q0)
        rows = np.asarray(indices, dtype=np.intp)
        self.qdot[rows] = 0.0
        self.last_command[rows] = 0.0
        self.steps[rows] = 0
        self._observe(rows)
        return [self._reset_info(int(index), q0) for index, q0 in zip(rows, q0s, strict=True)]

    def _reset_info(self, index: int, q0: np.ndarray) -> dict[str, Any]:
        error = self.error[index].copy()
        return {
            "error": error,
            "error_norm": float(np.linalg.norm(error)),
            "t": 0.0,
            "is_success": bool(error @ error <= self.template.success_tolerance**2),
            "reference": cast(Reference, self.references.references[index]).to_dict(),  # reset() set it
            "q0": q0.copy(),
        }

    def _observe(self, rows: Any = slice(None)) -> None:
        """Update x, x_d, ẋ_d and e of episodes ``rows`` from θ and the step count."""
        x = self.chain.forward(self.q[rows])
        x_d, xdot_d = self.references.evaluate(self.steps[rows] * self.dt, rows)
        self.x[rows], self.x_d[rows], self.xdot_d[rows] = x, x_d, xdot_d
        self.error[rows] = x - x_d  # e = x − x_d, as ObservationLayout.pack computes it

    # -- the batched step -------------------------------------------------------------------------
    def commands(self, actions: Any, ignored: np.ndarray | None = None) -> np.ndarray:
        """The applied joint velocities of an ``(N, m)`` action batch: checked, clipped, scaled.

        Args:
            actions: The actions in the template's action space, one row per episode.
            ignored: Rows whose action is not used (autoreset): NaN/inf there is not an error.

        Raises:
            ValueError: On a wrong shape or NaN/inf in a used row, naming the row.
        """
        try:
            raw = np.asarray(actions)
            if raw.dtype.kind not in "iuf":  # a complex, bool or string action is refused, not cast
                raise TypeError(raw.dtype)
            u = np.array(raw, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"actions must be an array of real numbers of shape {(self.count, len(self.limits))}, got {actions!r}"
            ) from exc
        if u.shape != (self.count, len(self.limits)):
            raise ValueError(f"actions must have shape {(self.count, len(self.limits))}, got {u.shape}")
        bad = ~np.isfinite(u).all(axis=1)
        if bad.any() and ignored is not None:
            bad &= ~ignored
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(f"action of sub-env {row} contains NaN or inf: {u[row].tolist()}")
        commands: np.ndarray
        if self.template.action_type == "normalized":
            commands = np.minimum(np.maximum(u, -1.0), 1.0) * self.limits
        else:
            commands = np.minimum(np.maximum(u, -self.limits), self.limits)
        return commands

    def step(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """Hold the commands ``u`` ``(N, m)`` for one period in every episode.

        Returns:
            Per-episode arrays: ``reward``, ``terminated``, ``truncated`` and the info fields
            (``cost_error``, ``cost_effort``, ``cost_smoothness``, ``error_norm``, ``is_success``).
        """
        template = self.template
        cost_error, cost_effort, cost_smoothness = step_costs(
            self.error, u, self.last_command, self.dt, template.Q, template.R
        )
        joint_step(self.q, u, self.dt, out=self.q)
        self.qdot = u.copy()
        self.last_command = u
        self.steps += 1
        self._observe()
        squared = np.einsum("ij,ij->i", self.error, self.error)
        success = squared <= template.success_tolerance**2
        error_norm = np.sqrt(squared)
        if template.reward_type == "dense":
            reward = -(cost_error + cost_effort)
        elif template.reward_type == "shaped":
            reward = shaped_reward(error_norm, u / self.limits)
        elif template.reward_type == "cost":  # minus the step's share of V, as the single env
            assert template.cost_convention is not None  # set for reward_type="cost"
            reward = -self.dt * template.cost_convention.step_rate(
                cost_error, cost_effort, cost_smoothness, first_step=self.steps == 1
            )
        else:
            reward = np.where(success, 0.0, -1.0)
        return {
            "reward": reward,
            "terminated": success & template.terminate_on_success,
            "truncated": self.steps >= self.horizon,
            "cost_error": cost_error,
            "cost_effort": cost_effort,
            "cost_smoothness": cost_smoothness,
            "error_norm": error_norm,
            "is_success": success,
        }

    def observations(self, rows: Any = slice(None)) -> np.ndarray:
        """The observations of episodes ``rows``, ``(len, d)``, in the template's observation dtype."""
        q = self.q[rows]
        clip = self.template.observation_clip  # finite_observation_bounds="clip": clipped in float64, as the single env
        obs = np.empty(
            (len(q), self.layout.size), dtype=np.float64 if clip is not None else self.template.observation_dtype
        )
        slices = self.layout.slices
        for name, value in (
            ("q", q),
            ("qdot", self.qdot[rows]),
            ("x", self.x[rows]),
            ("x_d", self.x_d[rows]),
            ("xdot_d", self.xdot_d[rows]),
            ("e", self.error[rows]),
            ("x_c", self.references.centre[rows]),
        ):
            obs[:, slices[name]] = value
        if clip is not None:
            return np.clip(obs, *clip).astype(self.template.observation_dtype)
        return obs


class URTaskVectorEnv(IdRobotCheck, gym.vector.VectorEnv):
    """N episodes of a task's env on the exact kinematic model, stepped at once (see the module docs).

    Build it with ``gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point",
    **kwargs)``; ``kwargs`` are the single env's (``robot``, ``dt``, ``max_steps``,
    ``reward_type``, ``action_type``, ``observation_dtype``, ``Q``, ``R``, ``success_tolerance``,
    ``terminate_on_success``, ``sample_space``, ``finite_observation_bounds``, ...), checked by
    building one single kinematic env from them. ``physics`` may only be ``"kinematic"`` (the
    episodes step the exact model θₖ₊₁ = θₖ + uₖΔt, not ``gym.make(id)``'s PyBullet: for PyBullet
    physics use ``vectorization_mode="sync"``); ``render_mode="rgb_array"`` makes :meth:`render`
    return the first episode's frame, drawn by PyBullet's scene.
    :class:`ReachVectorEnv` and :class:`EllipseTrackVectorEnv` fix the task; this class runs a
    task registered later, given ``task=``.

    Episodes truncate after ``max_steps`` if given, else ``max_episode_steps`` (``make_vec``
    passes the registered length), as the single env's ``TimeLimit`` does. Autoreset is
    ``AutoresetMode.NEXT_STEP`` (Gymnasium's default); ``reset(options={"reset_mask": mask})``
    resets only the masked sub-envs. ``step`` returns float64 rewards, bool flags and infos in
    the layout :class:`~gymnasium.vector.SyncVectorEnv` gives (each key with its ``_key`` mask):
    step infos ``error``, ``error_norm``, ``cost_error``, ``cost_effort``, ``cost_smoothness``,
    ``command``, ``t``, ``is_success``; a sub-env's reset info (``error``, ``error_norm``, ``t``,
    ``is_success``, ``reference``, ``q0``) in the step it is autoreset.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"]}
    #: The task of a subclass (``None``: given by ``task=``).
    task_spec: Task[Any] | None = None

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = None,
        physics: str = "kinematic",
        render_mode: str | None = None,
        task: Task[Any] | str | None = None,
        backend: str | None = None,
        **kwargs: Any,
    ) -> None:
        physics = physics_argument(physics, backend)
        if physics != "kinematic":
            raise ValueError(
                f"the vector env steps the kinematic model only (physics='kinematic'), got physics={physics!r}; "
                "for PyBullet use gym.make_vec(..., vectorization_mode='sync')"
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(
                f"the vector env renders render_mode='rgb_array' (its first episode's frame), got {render_mode!r}"
            )
        # the bound keeps a typo (10**9) from asking for terabytes
        whole_number("num_envs", num_envs, 1, MAX_NUM_ENVS)
        task = cast("Task[Any]", get_task(task if task is not None else self.task_spec))  # a registered task
        if not vector_env_supports(task):
            raise ValueError(
                f"the vector env steps end-effector positions only; task {task.name!r} has its own kinematics"
            )
        template = task_env_class(task)(physics="kinematic", task=task, **kwargs)
        if type(template.kinematics) is not Kinematics or template.kinematics.task_dim != 3:
            raise ValueError(
                f"the vector env steps end-effector positions only, got {type(template.kinematics).__name__}"
            )
        horizon = template.requested_max_steps or max_episode_steps or template.default_max_steps
        if horizon < 1:
            raise ValueError(f"max_episode_steps must be at least 1, got {max_episode_steps}")
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.single_env = template
        # The frame of episode 0, drawn by a PyBullet env of the same arguments (built at the first render)
        self._viewer_kwargs = {"task": task, **kwargs}
        self._viewer: URTaskEnv | None = None
        self.episodes = KinematicEpisodes(template, self.num_envs, horizon)
        self.max_episode_steps = int(horizon)
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(template.observation_space, self.num_envs)
        self.action_space = batch_space(template.action_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every sub-env (or those of ``options["reset_mask"]``); seeds as SyncVectorEnv takes them."""
        if self.closed:
            raise RuntimeError("reset() after close(): the vector env is closed; make a new one")
        super().reset(seed=seed if isinstance(seed, int) else None)
        seeds = seed_list(seed, self.num_envs)
        options = dict(options) if options is not None else None
        mask = reset_mask(options, self.num_envs)
        indices = np.flatnonzero(mask)
        infos = self._reset_infos(indices, [seeds[i] for i in indices], options)
        self._autoreset[indices] = False
        return self.episodes.observations(), infos

    def _reset_infos(
        self, indices: np.ndarray, seeds: Sequence[int | None], options: Mapping[str, Any] | None
    ) -> dict[str, Any]:
        infos: dict[str, Any] = {}
        for index, info in zip(indices, self.episodes.reset(indices, seeds, options), strict=True):
            infos = self._add_info(infos, info, int(index))
        return infos

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every sub-env; those whose episode ended in the last step are reset instead."""
        if self.closed:  # one attribute test: the episodes' arrays would go on stepping silently
            raise RuntimeError("step() after close(): the vector env is closed; make a new one")
        episodes = self.episodes
        resetting = self._autoreset
        u = episodes.commands(actions, ignored=resetting)
        result = episodes.step(u)
        infos = self._step_infos(result, u)
        reward, terminated, truncated = result["reward"], result["terminated"], result["truncated"]
        if resetting.any():
            indices = np.flatnonzero(resetting)
            reward[indices], terminated[indices], truncated[indices] = 0.0, False, False
            infos = merge_reset_infos(infos, self._reset_infos(indices, [None] * len(indices), None), resetting)
        self._autoreset = terminated | truncated
        return episodes.observations(), reward, terminated, truncated, infos

    def _step_infos(self, result: Mapping[str, np.ndarray], u: np.ndarray) -> dict[str, Any]:
        episodes = self.episodes
        values = {
            "error": episodes.error.copy(),
            "error_norm": result["error_norm"],
            "cost_error": result["cost_error"],
            "cost_effort": result["cost_effort"],
            "cost_smoothness": result["cost_smoothness"],
            "command": u.copy(),
            "t": episodes.steps * episodes.dt,
            "is_success": result["is_success"],
        }
        infos: dict[str, Any] = {}
        for key, value in values.items():
            infos[key], infos[f"_{key}"] = value, np.ones(self.num_envs, dtype=bool)
        return infos

    @property
    def robot(self) -> str:
        """The registered name of the robot the episodes drive."""
        return self.single_env.robot

    # gymnasium's VectorEnv.render returns a tuple of frames; this one returns episode 0's frame
    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """The frame of the first episode (sub-env 0), as ``gym.make(id, render_mode="rgb_array")`` draws it.

        The episodes step the exact kinematic model; the frame is drawn by PyBullet's scene with the
        arm set to episode 0's joint angles (a frame, not a simulation: the physics is the vector env's).
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make_vec")
            return None
        if self._viewer is None:
            self._viewer = task_env_class(self._viewer_kwargs["task"])(
                physics="pybullet", render_mode="rgb_array", **self._viewer_kwargs
            )
            self._viewer.reset(seed=0)
        viewer, episodes = self._viewer, self.episodes
        viewer.reference = cast(Reference, episodes.references.references[0])  # episode 0's, set by reset()
        viewer.steps = int(episodes.steps[0])
        viewer.arm.restore(episodes.q[0], episodes.qdot[0], episodes.last_command[0])  # markers parked too
        viewer._frame, viewer._shown_reference = None, None  # draw episode 0's state and path anew
        return viewer.render()

    def close_extras(self, **kwargs: Any) -> None:
        self.single_env.close()
        if self._viewer is not None:
            self._viewer.close()


def vector_env_supports(task: Task[Any]) -> bool:
    """Whether the batched env can run ``task``: its coordinates are the end-effector position.

    A task that overrides :meth:`Task.make_kinematics` (the pose tasks: orientation error by
    log3, task dimension 6) is not supported; :class:`PositionChain` and :class:`ReferenceBatch`
    know positions only.
    """
    return type(task).make_kinematics is Task.make_kinematics


class ReachVectorEnv(URTaskVectorEnv):
    """``snac_gym/<Robot>Reach-v0`` (:class:`~snac_gym.envs.task_envs.ReachEnv`), N episodes at once on the kinematic
    model."""

    task_spec = get_task("reach")


class EllipseTrackVectorEnv(URTaskVectorEnv):
    """``snac_gym/<Robot>EllipseTrack-v0`` (:class:`~snac_gym.envs.task_envs.EllipseTrackEnv`), N episodes at once."""

    task_spec = get_task("track")


def task_vector_env_class(task: Task[Any] | str) -> type[URTaskVectorEnv]:
    """The vector env class of ``task`` (the ``vector_entry_point`` of its ids): its own, or
    :class:`URTaskVectorEnv` for a task registered later (its ids pass ``task=``)."""
    task = get_task(task)
    for cls in (ReachVectorEnv, EllipseTrackVectorEnv):
        if cls.task_spec is task:
            return cls
    return URTaskVectorEnv
