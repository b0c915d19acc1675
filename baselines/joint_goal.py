"""Joint-space motion to a goal configuration inside the joint limits (``joint-goal``), a model-based controller.

At the first step of an episode it solves for the configuration θ* nearest θ₀ that puts the end
effector on x_d(0) inside the joint limits (:func:`snac_gym.model.joint_goal.nearest_goals`: IK from θ₀ and
from fixed spread starts, so other branches and the other way round a joint are found; for a moving
reference, preferably one with :data:`~snac_gym.model.joint_goal.TRACKING_ROOM` to every limit), then drives
the joints straight at it, following the virtual arm θ*(t) that carries the goal along a moving
reference (:class:`snac_gym.model.joint_goal.GoalArms`):

    u = sat(θ̇*(t) + K (θ*(t) − θ))

with ``sat`` the uniform scaling into the velocity limits. The joint box is convex, so the straight
joint path never leaves it: unlike the resolved-rate laws it keeps the joint limits without a clamp
that stalls. It is not a learner, and it is not an optimum: it moves straight in joint space, not
along the cheapest path. Position tasks (3-D) only.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from snac_gym.baselines._common import ObservationReader, scale_into_box

from snac_gym.model.joint_goal import TRACKING_ROOM, GoalArms
from snac_gym.policies.base import BasePolicy, positive_float, scale_rows_into_limits


class JointGoalPolicy(BasePolicy):
    """``u = sat(θ̇* + K(θ* − θ))`` towards the nearest in-limit IK goal (module docs).

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        gain: Joint-space feedback gain ``K``, 1/s; the effort knob (``effort_parameter``).

    Raises:
        ValueError: If ``gain`` is not positive, or the task is not a 3-D position task.
    """

    effort_parameter = "gain"

    def __init__(self, env: Any, gain: float = 2.0) -> None:
        super().__init__(env)
        self.gain = positive_float("gain", gain)
        if self.layout.task_dim != 3 or getattr(self.kinematics, "task_error", None) is not None:
            raise ValueError("joint-goal drives the 3-D position tasks (reach, track) only")
        self._reader = ObservationReader(self)
        slices = self.layout.slices
        self._x_d, self._xdot_d = (Ellipsis, slices["x_d"]), (Ellipsis, slices["xdot_d"])
        self.arms = GoalArms(
            self.kinematics,
            self.velocity_limits,
            self.dt,
            preferred_margin=TRACKING_ROOM if self.tracking else 0.0,
            moving=self.tracking,
        )
        self._started = False

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: the goal is solved at the first step."""
        self.internals = {}
        self._started = False

    def _commands(self, obs: np.ndarray) -> np.ndarray:
        q = obs[:, self._reader.q]
        if not self._started:
            self.arms.start(q, obs[self._x_d])
            self._started = True
        goal, velocity = self.arms.step(obs[self._x_d], obs[self._xdot_d])
        return velocity + self.gain * (goal - q)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for one observation, inside the velocity limits."""
        obs = self._reader.read(obs)
        command, scale = scale_into_box(self._commands(obs[None])[0], self.velocity_limits)
        self.internals = {"saturation_scale": scale, "goal_found": bool(self.arms.found[0])}
        return command

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` episodes."""
        self.reset()

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``: row i is :meth:`act` of row i."""
        obs_batch = self._reader.read_batch(obs_batch)
        return scale_rows_into_limits(self._commands(obs_batch), self.velocity_limits)
