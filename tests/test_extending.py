"""docs/extending.md, walked through: a new task, a new robot and a new controller, each in a few lines."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import snac_gym
from snac_gym.evaluation.samples import generate_samples, read_samples_csv, write_samples_csv
from snac_gym.envs import core as env_core
from snac_gym.kinematics import Kinematics
from snac_gym.policies import available_policies, make_policy, register_policy, registry
from snac_gym.policies.base import BasePolicy, PolicyContext, supports_batch
from snac_gym.references import FixedTarget
from snac_gym.robots import ROBOTS, Robot, register_robot
from snac_gym.rollout import rollout, simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import TASKS, ReachTask, Sample, Task, register_task


class HoverTask(ReachTask):
    """Reach a target at least 10 cm above the cuboid's floor, within 2 mm, in 10 s."""

    name, label, code = "hover", "Hover", 90
    env_name = "Hover"                                # its ids: snac_gym/UR10Hover-v0, snac_gym/PandaHover-v0, ...
    success_tolerance, episode_steps, horizon_s, real_horizon_s = 2e-3, 1250, 10.0, 12.0

    def sample(self, kinematics, rng, space):
        high = SampleSpace(**{**space.__dict__, "low": (*space.low[:2], space.low[2] + 0.1)})
        return super().sample(kinematics, rng, high)


@pytest.fixture
def hover():
    task = register_task(HoverTask())
    snac_gym.register_envs()
    yield task
    del TASKS[task.name]
    snac_gym.envs.unregister_envs(task=task.name)


def test_a_new_task_is_one_class_and_one_registration(hover, tmp_path):
    env = gym.make("snac_gym/UR10Hover-v0")
    assert env.spec.max_episode_steps == 1250 and env.unwrapped.task is hover
    assert type(env.unwrapped) is env_core.URTaskEnv and "snac_gym/XArm7Hover-v0" in gym.registry  # every robot's id
    check_env(env.unwrapped, skip_render_check=True)
    _, info = env.reset(seed=3)
    assert info["reference"]["target"][2] >= SampleSpace().low[2] + 0.1 - 1e-9
    steps = hover.horizon_steps(env.unwrapped.dt)
    log = rollout(env, make_policy("snac", env), options=hover.demo_options(), seed=0, steps=steps)
    assert np.linalg.norm(log.attrs["final_e"]) <= hover.success_tolerance
    env.close()
    # The evaluator draws, writes and reads its samples with no change.
    kinematics = Kinematics("ur10")
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, "hover", range(3))
    path = write_samples_csv(samples, tmp_path / "samples.csv", kinematics.n_joints)
    back = read_samples_csv(path, kinematics)["hover"]
    assert [s.index for s in back] == [0, 1, 2]
    np.testing.assert_array_equal(back[2].reference.target, samples[2].reference.target)


def test_a_task_name_or_code_is_registered_once(hover):
    with pytest.raises(ValueError, match="already registered"):
        register_task(HoverTask())
    clash = type("Clash", (HoverTask,), {"name": "clash"})
    with pytest.raises(ValueError, match="sample code 90 is already used by 'hover'"):
        register_task(clash())
    bare = type("Bare", (Task,), {"name": "bare", "code": 91})
    with pytest.raises(ValueError, match="Bare does not set \\['label', 'option_key'"):
        register_task(bare())


@pytest.fixture
def limited_ur10():
    robot = register_robot(Robot("ur10-limited", "ur_description/urdf/ur10_joint_limited_robot.urdf",
                                 nominal_q=ROBOTS["ur10"].nominal_q, env_prefix="UR10Limited"))
    snac_gym.register_envs()  # its ids: snac_gym/UR10LimitedReach-v0, ...
    yield robot
    del ROBOTS[robot.name]
    snac_gym.envs.unregister_envs(robot=robot.name)


def test_a_new_robot_is_one_entry(limited_ur10):
    limited, ur10 = Kinematics("ur10-limited"), Kinematics("ur10")
    q = np.array(limited_ur10.nominal_q)
    np.testing.assert_allclose(limited.forward(q), ur10.forward(q), atol=1e-12)  # the same arm ...
    assert limited.upper_limits.max() < ur10.upper_limits.max()  # ... with the URDF's tighter joint limits
    env = gym.make("snac_gym/UR10LimitedReach-v0", max_episode_steps=1500)
    check_env(env.unwrapped, skip_render_check=True)
    log = rollout(env, make_policy("snac", env), options=env.unwrapped.task.demo_options(), seed=0, steps=1500)
    assert np.linalg.norm(log.attrs["final_e"]) <= 1e-3
    env.close()


class ResolvedRate(BasePolicy):
    """u = J⁺(ẋ_d − k·e): the controller of docs/extending.md, with its effort knob k."""

    effort_parameter = "gain"

    def __init__(self, env, gain: float = 2.0) -> None:
        super().__init__(env)
        self.gain = float(gain)

    def act(self, obs):
        f = self.layout.unpack(obs)
        return np.linalg.pinv(self.kinematics.jacobian(f.q)) @ (f.xdot_d - self.gain * f.e)


@pytest.fixture
def resolved_rate(monkeypatch):
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))  # the registration ends with the test
    register_policy("resolved-rate", ResolvedRate)
    return ResolvedRate


def test_a_new_controller_runs_in_the_env_and_the_kinematic_engine(resolved_rate):
    assert "resolved-rate" in available_policies() and not supports_batch(resolved_rate)
    env = gym.make("snac_gym/UR10EllipseTrack-v0")
    log = rollout(env, make_policy("resolved-rate", env, gain=4.0), options=env.unwrapped.task.demo_options(), seed=0)
    assert np.linalg.norm(log[["e_0", "e_1", "e_2"]].to_numpy()[-500:], axis=1).max() < 5e-3
    env.close()
    kinematics = Kinematics("ur10")
    context = PolicyContext(kinematics, 1 / 125, kinematics.velocity_limits, env.unwrapped.obs_layout, "reach")
    sample = Sample("reach", 0, np.array(ROBOTS["ur10"].nominal_q), FixedTarget([-0.6, 0.3, 0.4]))
    weak, strong = (
        simulate_kinematic(context, lambda g=g: make_policy("resolved-rate", context, gain=g), [sample], 50, [0])
        for g in (1.0, 4.0)
    )
    assert np.abs(strong.commands).max() > np.abs(weak.commands).max()  # the knob scales effort
