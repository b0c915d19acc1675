"""docs/extending.md, walked through: a new task, a new robot and a new controller, each in a few lines.

Each fixture runs its recipe's code block as the page writes it (read from the page, so the two cannot
drift), then the tests check what the page promises.
"""

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from snac_gym.evaluation.samples import generate_samples, read_samples_csv, write_samples_csv

import snac_gym
from snac_gym.envs import core as env_core
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import ROBOTS
from snac_gym.policies import available_policies, make_policy, registry
from snac_gym.policies.base import PolicyContext, supports_batch
from snac_gym.references import FixedTarget
from snac_gym.rollout import rollout, simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import TASKS, Sample, Task, register_task

PAGE = Path(__file__).resolve().parents[2] / "docs" / "extending.md"


def recipe(heading: str) -> dict:
    """Run the first ``python`` block under ``## heading`` of docs/extending.md; its namespace."""
    text = PAGE.read_text()
    section = text[text.index(f"## {heading}\n") :]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    namespace: dict = {"__name__": "extending_recipe"}
    exec(compile(block, f"{PAGE}:{heading}", "exec"), namespace)
    return namespace


@pytest.fixture
def hover():
    namespace = recipe("How to add a task")
    task = TASKS["hover"]
    assert type(task) is namespace["HoverTask"]
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
        register_task(type(hover)())
    clash = type("Clash", (type(hover),), {"name": "clash"})
    with pytest.raises(ValueError, match="sample code 90 is already used by 'hover'"):
        register_task(clash())
    methods = {name: lambda self, *args: None for name in Task.__abstractmethods__}  # the methods, not the attributes
    bare = type("Bare", (Task,), {"name": "bare", "code": 91, **methods})
    with pytest.raises(ValueError, match="Bare does not set \\['label', 'option_key'"):
        register_task(bare())


@pytest.fixture
def limited_ur10():
    namespace = recipe("How to add a robot")
    robot = ROBOTS["ur10-limited"]
    assert namespace["env"].spec.id == "snac_gym/UR10LimitedReach-v0"
    namespace["env"].close()
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


@pytest.fixture
def resolved_rate(monkeypatch):
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))  # the registration ends with the test
    return recipe("How to add a controller")["ResolvedRate"]


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


def test_a_task_that_leaves_out_part_of_the_contract_cannot_be_made():
    from snac_gym.tasks.base import Task

    class Half(Task):
        name = "half"

        def sample(self, kinematics, rng, space):  # the other five are missing
            raise AssertionError

    with pytest.raises(TypeError, match="abstract methods") as refused:
        Half()
    # Python 3.12 quotes the names; 3.11 does not, so the names are checked one by one.
    missing = re.findall(r"\w+", str(refused.value).split("abstract methods", 1)[1])
    assert missing == ["csv_cells", "option_value", "paper", "parse", "read_csv_reference"]
