"""``reward_type="cost"``: the env's return is minus the evaluator's trajectory cost under a convention.

The env's reward comes from its per-step cost terms (snac_gym/envs/core.py, vector.py); the evaluator's
cost from whole trajectories (:func:`snac_gym.metrics.rollout_metrics` on :func:`simulate_kinematic`'s
rollouts). The two are separate code paths; these tests run the same controller on the same sample
through both and compare the numbers.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import EvaluationSample

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.control.cost import CostConvention
from snac_gym.metrics import rollout_metrics
from snac_gym.policies import make_policy
from snac_gym.rollout import simulate_kinematic

CONVENTIONS = [
    CostConvention(),  # the paper's Table I cost, u₋₁ = 0
    CostConvention("hjb", q_scale=4.0),  # the critics' comparison: HJB cost, Q = 4I
    CostConvention("table1", udot_start="first", q_scale=1e6),  # no jump from rest, error in mm²
]
IDS = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}
STEPS = 400


def _episode_return(env_id: str, convention: CostConvention, controller: str, seed: int):
    """Run ``controller`` for STEPS steps in the kinematic env with the cost reward; the return and the sample."""
    env = gym.make(env_id, physics="kinematic", reward_type="cost", cost=convention, max_episode_steps=STEPS)
    obs, info = env.reset(seed=seed)
    q0 = info["q0"]
    policy = make_policy(controller, env)
    policy.reset(seed=seed)
    total, steps, done = 0.0, 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        total += reward
        steps += 1
        done = terminated or truncated
    base = env.unwrapped
    sample = EvaluationSample(base.task.name, 0, q0, base.reference)
    env.close()
    return total, steps, sample


@pytest.mark.parametrize("task", sorted(IDS))
@pytest.mark.parametrize("convention", CONVENTIONS, ids=lambda c: f"{c.cost}-{c.udot_start}-q{c.q_scale:g}")
def test_the_return_is_minus_the_evaluators_cost(task, convention):
    """Σ rewards = −V of the evaluator's rollout of the same sample and controller, to 1e-10 relative."""
    total, steps, sample = _episode_return(IDS[task], convention, "dls", seed=3)
    assert steps == STEPS
    context = policy_context("ur10", 1 / 125, task)
    rollouts = simulate_kinematic(context, lambda: make_policy("dls", context), [sample], STEPS, [3])
    cost = rollout_metrics(rollouts, task, context.velocity_limits, convention)["cost"].iloc[0]
    assert cost > 0
    assert -total == pytest.approx(cost, rel=1e-10)


def test_the_reward_is_the_step_share_of_the_cost_by_hand():
    """Step by step: r_k = −Δt (eₖᵀQeₖ + uₖᵀuₖ + [k > 0 or u₋₁ = 0] u̇ₖᵀu̇ₖ) with eₖ the error before the step."""
    convention = CostConvention("table1", udot_start="first", q_scale=9.0)
    env = gym.make(IDS["reach"], physics="kinematic", reward_type="cost", cost=convention)
    obs, info = env.reset(seed=1)
    dt, previous = env.unwrapped.dt, None
    rng = np.random.default_rng(0)
    limits = env.unwrapped.velocity_limits
    for k in range(5):
        error = info["error"].copy()
        u = rng.uniform(-0.5, 0.5, size=6) * limits
        obs, reward, _, _, info = env.step(u)
        udot = np.zeros(6) if previous is None else (u - previous) / dt
        expected = -dt * (9.0 * error @ error + u @ u + udot @ udot)
        assert reward == pytest.approx(expected, rel=1e-12), k
        previous = u
    env.close()


def test_the_vector_env_gives_the_single_envs_rewards():
    convention = CostConvention("hjb", q_scale=4.0)
    single = gym.make(IDS["track"], physics="kinematic", reward_type="cost", cost=convention)
    vector = gym.make_vec(
        IDS["track"], num_envs=2, vectorization_mode="vector_entry_point", reward_type="cost", cost=convention
    )
    obs, _ = single.reset(seed=4)
    batch, _ = vector.reset(seed=[4, 5])
    np.testing.assert_allclose(batch[0], obs, rtol=0, atol=1e-12)
    rng = np.random.default_rng(1)
    for _ in range(20):
        u = rng.uniform(-0.3, 0.3, size=(2, 6))
        _, reward, *_ = single.step(u[0])
        _, rewards, *_ = vector.step(u)
        assert rewards[0] == pytest.approx(reward, rel=1e-12)
    single.close()
    vector.close()


def test_cost_without_the_cost_reward_is_refused():
    with pytest.raises(ValueError, match="cost= sets the reward of reward_type='cost', got reward_type='dense'"):
        gym.make(IDS["reach"], physics="kinematic", cost=CostConvention("hjb"))


def test_q_or_r_beside_the_cost_reward_is_refused():
    with pytest.raises(ValueError, match="takes Q and R from cost="):
        gym.make(IDS["reach"], physics="kinematic", reward_type="cost", Q=[2.0, 2.0, 2.0])


def test_a_cost_that_is_not_a_convention_is_refused():
    with pytest.raises(ValueError, match="cost must be a snac_gym.control.cost.CostConvention, got 'hjb'"):
        gym.make(IDS["reach"], physics="kinematic", reward_type="cost", cost="hjb")


# -- PPO's training reward ------------------------------------------------------------------------
def _ppo_config(task: str, **reward) -> dict:
    import copy

    from snac_gym.ppo.config import default_config_path, load_config, validate_config

    config = copy.deepcopy(load_config(default_config_path(task)))
    config["reward"] = {**config["reward"], "type": "cost", **reward}
    config["env"] = {**config["env"], "physics": "kinematic"}
    validate_config(config)
    return config


@pytest.mark.rl
def test_ppo_trains_on_minus_the_cost_in_the_single_and_the_batched_env():
    """reward.type 'cost': the training wrapper's and the batched env's rewards are the env's cost reward,
    and their sum over an episode's first steps is −V of the same commands (the convention's)."""
    from snac_gym.control.cost import trajectory_cost
    from snac_gym.ppo.train import make_training_env
    from snac_gym.ppo.vec_env import PPOVecEnv

    config = _ppo_config("track", cost="hjb", q_scale=4.0)
    single = make_training_env(config)
    batched = PPOVecEnv(config, num_envs=1)
    single.reset(seed=7)
    batched.seed(7)
    batched.reset()
    rng = np.random.default_rng(2)
    errors, commands, total, batched_total = [], [], 0.0, 0.0
    for _ in range(30):
        action = rng.uniform(-1, 1, size=single.action_space.shape[0])  # 3: the shipped configs act in task space
        errors.append(single.unwrapped._obs[single.unwrapped._error_slice].copy())
        _, reward, _, _, info = single.step(action)
        assert reward == info["env_reward"]
        commands.append(info["command"])
        total += reward
        batched_total += float(batched.step(action[None].astype(np.float32))[1][0])
    terms = trajectory_cost(np.array(errors)[None], np.array(commands)[None], single.unwrapped.dt, Q=4.0 * np.eye(3))
    assert -total == pytest.approx(float(terms.error[0] + terms.effort[0]), rel=1e-10)
    assert batched_total == pytest.approx(total, rel=1e-6)  # float32 actions in the batched env
    single.close()
    batched.close()


def test_a_ppo_config_with_the_cost_reward_and_its_own_env_reward_is_refused():
    import copy

    from snac_gym.ppo.config import ConfigError, default_config_path, load_config, validate_config

    config = copy.deepcopy(load_config(default_config_path("reach")))
    config["reward"] = {**config["reward"], "type": "cost"}
    config["env"] = {**config["env"], "reward_type": "dense"}
    with pytest.raises(ConfigError, match="reward.type 'cost' sets the env's reward_type"):
        validate_config(config)
    config["env"].pop("reward_type")
    config["reward"]["udot_start"] = "never"
    with pytest.raises(ConfigError, match="udot_start"):
        validate_config(config)
