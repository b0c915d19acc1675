"""Behaviour cloning of the reference for the goal-relative policy (``ppo-workspace``): targets, fit, export.

The expert is the evaluator's reference (the constrained optimum of each sample); its command sequences and the
observations they produce are recorded by ``docs/scripts/ppo_cloning.py`` (this package sits below the evaluator
and cannot call it). Here:

* :func:`target_actions`: the goal-relative action a ∈ [−1, 1]ⁿ⁺¹ whose command is nearest the reference's u.
  The command is affine in a before the saturation (:func:`~snac_gym.ppo.features.goal_relative_command`),

      u = θ̇* + s·k·(θ* − θ) + [s·k·(θ* − θ) | s·g·(‖e‖ + ε_v)·Jᵀ(JJᵀ + λ²I)⁻¹] a,

  so a is a ridge least-squares fit of n + 1 unknowns to m equations (the ridge pulls towards a = 0, the
  ``joint-goal`` command, where the columns vanish at the target), clipped to the box;
* :func:`fit_actor`: the actor of the shipped architecture (``ppo.net_arch.pi`` hidden layers, the config's
  activation) fitted to those targets by weighted mean squared error, with torch;
* :func:`cloned_policy_file`: that actor as a :class:`~snac_gym.ppo.policy_file.PolicyFile` (no observation
  normalisation, as the goal configs train), and :func:`load_actor`, which puts a policy file's actor into an SB3
  model (``ppo.init_from`` of a config: PPO fine-tuning from the clone).
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

import numpy as np

from snac_gym.model.kinematics import damped_least_squares
from snac_gym.observation import ObservationLayout
from snac_gym.ppo.features import RELATIVE_ERROR_FLOOR, FeatureSpec, GoalState
from snac_gym.ppo.policy_file import PolicyFile

#: Ridge of the target's least squares, (rad/s)²: below ~1 mrad/s of command a column does not move a off 0.
TARGET_RIDGE = 1e-6


def action_columns(
    obs: np.ndarray, layout: ObservationLayout, jacobians: np.ndarray, spec: FeatureSpec, goal: GoalState
) -> tuple[np.ndarray, np.ndarray]:
    """The affine form of the goal-relative command before saturation, at effort 1: ``u = base + C a``.

    Returns:
        ``base`` ``(B, m)`` (the ``joint-goal`` command, unsaturated) and ``C`` ``(B, m, n + 1)``.
    """
    obs = np.asarray(obs, dtype=np.float64)
    s = layout.slices
    e = obs[:, s["e"]]
    pull = np.asarray(goal.goal, dtype=np.float64) - obs[:, s["q"]]
    n = layout.task_dim
    # Jᵀ(JJᵀ + λ²I)⁻¹ itself: the damped least squares of the identity's columns (the unit task velocities)
    identity = np.broadcast_to(np.eye(n), (len(obs), n, n))
    resolved = damped_least_squares(np.asarray(jacobians, dtype=np.float64), identity, spec.damping**2 * np.eye(n))
    error_norm = np.sqrt(np.sum(e * e, axis=-1))
    task = spec.gain_max * (error_norm + RELATIVE_ERROR_FLOOR)[:, None, None] * resolved
    columns = np.concatenate((spec.joint_gain * pull[:, :, None], task), axis=-1)
    return np.asarray(goal.velocity, dtype=np.float64) + spec.joint_gain * pull, columns


def target_actions(
    obs: np.ndarray,
    commands: np.ndarray,
    layout: ObservationLayout,
    jacobians: np.ndarray,
    spec: FeatureSpec,
    goal: GoalState,
    ridge: float = TARGET_RIDGE,
    pull_floor: float = -1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The action nearest each command ``(B, m)``: ridge least squares on :func:`action_columns`, clipped to [−1, 1].

    ``pull_floor``: the least a₀ (the joint-space pull's factor, 1 + a₀ times ``joint_gain``); where the fit's a₀
    is below it, a₀ is set to it and a₁..ₙ fitted again with it fixed (the reference ends its reach with a weak
    pull, slower than the 1 mm success needs: docs/ppo.md).

    Returns:
        ``actions`` ``(B, n + 1)`` and the relative residual ‖u − u(a)‖ / (‖u − base‖ + 1e-9) of each row, with
        u(a) the unsaturated command of the clipped action.
    """
    base, columns = action_columns(obs, layout, jacobians, spec, goal)
    wanted = np.asarray(commands, dtype=np.float64) - base
    normal = np.einsum("bmi,bmj->bij", columns, columns) + ridge * np.eye(columns.shape[-1])
    actions = np.linalg.solve(normal, np.einsum("bmi,bm->bi", columns, wanted)[..., None])[..., 0]
    low = actions[:, 0] < pull_floor
    if low.any():  # a₀ fixed at the floor, the task-space part fitted to what is left
        rest, task = wanted[low] - pull_floor * columns[low, :, 0], columns[low, :, 1:]
        normal = np.einsum("bmi,bmj->bij", task, task) + ridge * np.eye(task.shape[-1])
        actions[low, 0] = pull_floor
        actions[low, 1:] = np.linalg.solve(normal, np.einsum("bmi,bm->bi", task, rest)[..., None])[..., 0]
    actions = np.clip(actions, -1.0, 1.0)
    missed = wanted - np.einsum("bmi,bi->bm", columns, actions)
    residual = np.linalg.norm(missed, axis=-1) / (np.linalg.norm(wanted, axis=-1) + 1e-9)
    return actions, residual


def fit_actor(
    features: np.ndarray,
    targets: np.ndarray,
    weights: np.ndarray | None = None,
    hidden: tuple[int, ...] = (64, 64),
    activation: str = "tanh",
    epochs: int = 30,
    batch_size: int = 4096,
    learning_rate: float = 1e-3,
    seed: int = 0,
    log: Any = None,
) -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], tuple[np.ndarray, np.ndarray]]:
    """An MLP ``features → targets`` fitted by weighted MSE with Adam (cosine-decayed rate); float32 layers.

    Returns:
        The hidden layers ``((weight (out, in), bias), ...)`` and the output layer, as a policy file holds them.
    """
    import torch  # the rl extra; the fitted file is read without torch

    torch.manual_seed(seed)
    act = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[activation]
    layers: list[torch.nn.Module] = []
    width = features.shape[1]
    for size in hidden:
        layers += [torch.nn.Linear(width, size), act()]
        width = size
    output = torch.nn.Linear(width, targets.shape[1])
    with torch.no_grad():  # start at a = 0, the joint-goal command, as a fresh SB3 actor nearly does
        output.weight.mul_(0.01)
        output.bias.zero_()
    net = torch.nn.Sequential(*layers, output)
    x = torch.as_tensor(np.asarray(features, dtype=np.float32))
    y = torch.as_tensor(np.asarray(targets, dtype=np.float32))
    w = torch.as_tensor(np.ones(len(x), np.float32) if weights is None else np.asarray(weights, np.float32))
    w = w / w.mean()
    optimiser = torch.optim.Adam(net.parameters(), lr=learning_rate)
    batches = max(1, int(np.ceil(len(x) / batch_size)))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs * batches)
    generator = torch.Generator().manual_seed(seed)
    for epoch in range(epochs):
        order = torch.randperm(len(x), generator=generator)
        total = 0.0
        for b in range(batches):
            rows = order[b * batch_size : (b + 1) * batch_size]
            loss = (w[rows, None] * (net(x[rows]) - y[rows]) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += float(loss.detach()) * len(rows)
        if log is not None and (epoch % 5 == 4 or epoch == epochs - 1):
            log(f"epoch {epoch + 1}/{epochs}: weighted MSE {total / len(x):.5f}")
    linear = [m for m in net if isinstance(m, torch.nn.Linear)]
    arrays = tuple(
        (m.weight.detach().numpy().astype(np.float32).copy(), m.bias.detach().numpy().astype(np.float32).copy())
        for m in linear
    )
    return arrays[:-1], arrays[-1]


def cloned_policy_file(
    hidden: tuple[tuple[np.ndarray, np.ndarray], ...],
    output: tuple[np.ndarray, np.ndarray],
    config: dict[str, Any],
    layout: ObservationLayout,
    extra: dict[str, Any] | None = None,
) -> PolicyFile:
    """The fitted actor as a policy file of ``config``'s task, robot and features (no observation normalisation)."""
    policy = PolicyFile(
        hidden=hidden,
        action_layer=output,
        activation=str(config["ppo"].get("activation", "tanh")),
        obs_mean=None,
        obs_var=None,
        obs_epsilon=1e-8,
        obs_clip=float("inf"),
        features=FeatureSpec.from_dict(config["features"]),
        metadata={
            "task": config["task"],
            "robot": config.get("robot", "ur10"),
            "layout": {"n_joints": layout.n_joints, "task_dim": layout.task_dim, "size": layout.size},
            "timesteps": 0,
            "seed": int(config.get("seed", 0)),
            "config": config,
            "exported_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            **(extra or {}),
        },
    )
    policy.validate("cloned policy")
    return policy


def load_actor(model: Any, policy: PolicyFile) -> None:
    """Copy a policy file's actor into an SB3 ``MlpPolicy`` of the same architecture (the critic is left as is).

    Raises:
        ValueError: If the layers' shapes differ.
    """
    import torch  # the rl extra

    linear = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    if len(linear) != len(policy.hidden):
        raise ValueError(f"init_from has {len(policy.hidden)} hidden layers, the model {len(linear)}")
    pairs = [*zip(linear, policy.hidden, strict=True), (model.policy.action_net, policy.action_layer)]
    with torch.no_grad():
        for module, (weight, bias) in pairs:
            if tuple(module.weight.shape) != weight.shape:
                raise ValueError(
                    f"init_from layer {weight.shape} does not fit the model's {tuple(module.weight.shape)}"
                )
            module.weight.copy_(torch.as_tensor(weight))
            module.bias.copy_(torch.as_tensor(bias))
