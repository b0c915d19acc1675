"""The policy registry (built-ins, register_policy, the ``snac_gym.policies`` entry-point group)
and the Policy contract for every policy that imports."""

import importlib.metadata

import gymnasium as gym
import numpy as np
import pytest

from snac_gym.policies import ENTRY_POINT_GROUP, Policy, available_policies, make_policy, register_policy, registry
from snac_gym.policies.base import BasePolicy, PolicyContext
from snac_gym.policies.snac import SNACPolicy
from snac_gym.references import PAPER_Q0

ENV_OF_TASK = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}


@pytest.fixture
def isolated_registry(monkeypatch):
    """Registrations made in a test vanish after it."""
    monkeypatch.setattr(registry, "_BUILTIN", dict(registry._BUILTIN))
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))


@pytest.fixture(scope="module")
def envs():
    made = {task: gym.make(env_id) for task, env_id in ENV_OF_TASK.items()}
    yield made
    for env in made.values():
        env.close()


class _Constant(BasePolicy):
    """Commands a constant velocity; stands in for a third-party package's policy."""

    def __init__(self, env, speed=0.1):
        super().__init__(env)
        self.speed = speed

    def _act(self, obs):
        return np.full(self.kinematics.n_joints, self.speed)


def test_snac_is_built_in_for_both_tasks(envs):
    assert "snac" in available_policies()
    for task, env in envs.items():
        policy = make_policy("snac", env, seed=1)
        assert isinstance(policy, SNACPolicy) and isinstance(policy, Policy)
        assert policy.task == task
        assert policy.basis.size == (6 if task == "reach" else 21)
    # kwargs reach the constructor; a PolicyContext works as well as an env
    context = PolicyContext.from_env(envs["track"])
    assert make_policy("snac", context, command_scale=0.5).command_scale == 0.5


def test_entry_point_group_registers_a_policy(monkeypatch, envs):
    entry = importlib.metadata.EntryPoint(name="ep-constant", value=f"{__name__}:_Constant", group=ENTRY_POINT_GROUP)
    entry_snac = importlib.metadata.EntryPoint(
        name="ep-snac", value="snac_gym.policies.snac:SNACPolicy", group=ENTRY_POINT_GROUP
    )
    seen_groups = []

    def fake_entry_points(**selection):
        seen_groups.append(selection.get("group"))
        return [ep for ep in (entry, entry_snac) if ep.group == selection.get("group")]

    monkeypatch.setattr(registry.importlib.metadata, "entry_points", fake_entry_points)
    names = available_policies()
    assert {"ep-constant", "ep-snac", "snac"} <= set(names)
    assert seen_groups and set(seen_groups) == {ENTRY_POINT_GROUP}
    policy = make_policy("ep-constant", envs["reach"], speed=0.25)
    assert type(policy).__name__ == "_Constant"
    np.testing.assert_array_equal(policy.act(np.zeros(27)), np.full(6, 0.25))
    assert isinstance(make_policy("ep-snac", envs["track"]), SNACPolicy)


def test_entry_points_are_gone_when_the_package_is(monkeypatch):
    monkeypatch.setattr(registry.importlib.metadata, "entry_points", lambda **selection: [])
    assert "ep-constant" not in available_policies()
    with pytest.raises(ValueError, match="unknown policy 'ep-constant'"):
        make_policy("ep-constant", None)


def test_register_policy_callable_and_string(isolated_registry, envs):
    register_policy("constant-test", _Constant)
    assert "constant-test" in available_policies()
    assert make_policy("constant-test", envs["reach"], speed=0.3).speed == 0.3
    with pytest.raises(ValueError, match="already registered"):
        register_policy("constant-test", _Constant)
    with pytest.raises(ValueError, match="already registered"):
        register_policy("snac", _Constant)
    register_policy("constant-test", "snac_gym.policies.snac:SNACPolicy", overwrite=True)
    assert isinstance(make_policy("constant-test", envs["reach"]), SNACPolicy)
    with pytest.raises(ValueError, match="alphanumeric"):
        register_policy("bad name!", _Constant)


@pytest.mark.parametrize("name", available_policies())
def test_every_available_policy_keeps_the_contract(name, envs):
    """reset/act on both tasks: finite commands of the right shape, inside the limits, reproducible."""
    for env in envs.values():
        try:
            policy = make_policy(name, env)
        except (ImportError, FileNotFoundError) as exc:  # optional dependency or trained model not installed
            pytest.skip(f"{name}: {exc}")
        assert isinstance(policy, Policy)
        runs = []
        for _ in range(2):
            obs, _ = env.reset(seed=3, options={"q0": list(PAPER_Q0)})
            policy.reset(seed=3)
            commands = []
            for _ in range(15):
                u = np.asarray(policy.act(obs), dtype=float)
                assert u.shape == (6,) and np.all(np.isfinite(u))
                assert np.all(np.abs(u) <= env.unwrapped.velocity_limits + 1e-12)
                assert isinstance(policy.internals, dict)
                commands.append(u.copy())
                obs, *_ = env.step(u)
            runs.append(np.array(commands))
        np.testing.assert_array_equal(runs[0], runs[1])
