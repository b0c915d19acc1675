"""One id per robot and task, the explicit env classes, and the one kinematic step θₖ₊₁ = θₖ + uₖΔt.

The UR10 ids, the robot= path of 0.1.0 and the three kinematic steppers are compared bit for bit
with trajectories recorded before the change (tests/data/record_ur10_trajectories.py, at 089c544).

Bit for bit holds where OpenBLAS runs the kernels of the recording (Haswell's, which it also runs on
Zen). OpenBLAS picks its kernels by CPU, and its AVX-512 ones (SkylakeX, chosen on AVX-512 CPUs) or
older ones sum the small products in another order: the same code then differs in the last bits
(measured with OPENBLAS_CORETYPE=SkylakeX: at most 1.3e-14 relative, on the Panda's observations), so
there the comparison is to 1e-12 relative.
"""

import inspect
import re
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import threadpoolctl
from gymnasium.utils.env_checker import check_env

import snac_gym
from snac_gym.envs import GOAL_ENV_IDS, REGISTERED_IDS, V0_NOTICE, core, make_task_env, task_envs, vector
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import ROBOTS
from snac_gym.physics import KinematicArm
from snac_gym.tasks import TASKS

DATA = Path(__file__).parents[1] / "data"
sys.path.insert(0, str(DATA))
import record_ur10_trajectories as recorded  # noqa: E402

from snac_gym.envs.goal import coarse_reach_id  # noqa: E402

RECORDED = np.load(DATA / "ur10_trajectories.npz")
NEW_IDS = [
    f"snac_gym/{prefix}{name}-v0" for prefix in ("UR3", "UR5", "Panda", "XArm7") for name in ("Reach", "EllipseTrack")
]


#: OpenBLAS's kernels that made the recording; NumPy's matrix products run through them.
RECORDING_BLAS = {"Haswell", "Zen"}
BLAS = {info.get("architecture") for info in threadpoolctl.threadpool_info() if info["internal_api"] == "openblas"}


def _assert_recorded(name, arrays):
    for key, value in arrays.items():
        expected = RECORDED[f"{name}_{key}"]
        if BLAS and BLAS <= RECORDING_BLAS:
            np.testing.assert_array_equal(value, expected, err_msg=f"{name}_{key}")
        else:
            error = np.abs(np.asarray(value, dtype=float) - expected) / np.maximum(np.abs(expected), 1.0)
            assert error.max() <= 1e-12, (f"{name}_{key}", error.max(), BLAS)


# -- the ids ------------------------------------------------------------------------------------------
def test_one_id_per_robot_and_task_from_the_registries():
    expected = {task.env_id_for(robot) for task in TASKS.values() for robot in ROBOTS}
    assert expected == set(snac_gym.ENV_IDS)
    goal_ids = {task.env_id_for(robot, goal=True) for task in TASKS.values() for robot in ROBOTS}
    coarse = {coarse_reach_id(robot, action) for robot in ROBOTS for action in ("joint", "cartesian")}
    assert goal_ids | coarse == set(GOAL_ENV_IDS)
    assert {
        "snac_gym/PandaReach-v0",
        "snac_gym/XArm7EllipseTrack-v0",
        "snac_gym/UR5Reach-v0",
        "snac_gym/UR3EllipseTrack-v0",
        "snac_gym/PandaReachGoal-v0",
        "snac_gym/XArm7EllipseTrackGoal-v0",
    } <= set(gym.registry)
    # The UR10 ids keep their names and lengths.
    assert gym.spec("snac_gym/UR10Reach-v0").max_episode_steps == 1000
    assert gym.spec("snac_gym/UR10EllipseTrack-v0").max_episode_steps == 2500
    assert REGISTERED_IDS["snac_gym/XArm7EllipseTrack-v0"].robot == "xarm7"


@pytest.mark.parametrize("env_id", NEW_IDS)
def test_new_ids_pass_check_env_on_the_kinematic_model(env_id):
    env = gym.make(env_id, physics="kinematic")
    assert env.unwrapped.robot == REGISTERED_IDS[env_id].robot
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", ["snac_gym/PandaReach-v0", "snac_gym/XArm7EllipseTrack-v0"])
def test_new_ids_pass_check_env_in_pybullet_headless(env_id, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)  # the checker also builds render_mode="human"
    env = gym.make(env_id)
    assert env.unwrapped.physics == "pybullet" and env.unwrapped.kinematics.n_joints == 7
    check_env(env.unwrapped)
    env.close()


def test_goal_ids_of_other_robots_pass_check_env():
    env = gym.make("snac_gym/PandaReachGoal-v0", physics="kinematic")
    assert env.unwrapped.robot == "panda" and env.observation_space["observation"].shape == (14,)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


# -- robot= on another robot's id -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "make, right",
    [
        (lambda: gym.make("snac_gym/UR10Reach-v0", robot="panda"), "snac_gym/PandaReach-v0"),
        (
            lambda: gym.make("snac_gym/PandaEllipseTrack-v0", robot="ur5", physics="kinematic"),
            "snac_gym/UR5EllipseTrack-v0",
        ),
        (lambda: gym.make("snac_gym/UR10ReachGoal-v0", robot="xarm7"), "snac_gym/XArm7ReachGoal-v0"),
        (
            lambda: gym.make_vec("snac_gym/UR10Reach-v0", 2, vectorization_mode="vector_entry_point", robot="ur3"),
            "snac_gym/UR3Reach-v0",
        ),
        (
            lambda: gym.make_vec("snac_gym/UR10Reach-v0", 2, vectorization_mode="sync", robot="ur3"),
            "snac_gym/UR3Reach-v0",
        ),
    ],
    ids=["single", "kinematic", "goal", "vector", "sync"],
)
def test_robot_of_another_id_is_refused_naming_the_right_id(make, right):
    with pytest.raises(ValueError) as caught:
        make()
    message = str(caught.value)
    assert f"use gym.make('{right}')" in message and "is the id of the" in message


def test_the_ids_own_robot_may_be_named():
    env = gym.make("snac_gym/UR10Reach-v0", robot="UR10", physics="kinematic")  # robot names are case-insensitive
    assert env.unwrapped.robot == "ur10"
    env.close()
    assert make_task_env("track", "xarm7", physics="kinematic").spec.id == "snac_gym/XArm7EllipseTrack-v0"


# -- bit for bit as before -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, env_id, seed, kwargs",
    [
        ("reach_pybullet", "snac_gym/UR10Reach-v0", 7, {}),
        ("track_pybullet", "snac_gym/UR10EllipseTrack-v0", 8, {}),
        ("reach_kinematic", "snac_gym/UR10Reach-v0", 7, {"physics": "kinematic"}),
        ("track_kinematic", "snac_gym/UR10EllipseTrack-v0", 8, {"physics": "kinematic"}),
        ("reach_normalized_shaped", "snac_gym/UR10Reach-v0", 9, {"action_type": "normalized", "reward_type": "shaped"}),
        # 0.1.0's robot= on the UR10 id is now the robot's own id, with the same numbers.
        ("panda_reach_pybullet", "snac_gym/PandaReach-v0", 7, {}),
        ("panda_track_kinematic", "snac_gym/PandaEllipseTrack-v0", 8, {"physics": "kinematic"}),
        ("ur5_reach_pybullet", "snac_gym/UR5Reach-v0", 7, {}),
    ],
)
def test_trajectories_are_bit_identical_to_the_recorded_ones(name, env_id, seed, kwargs):
    _assert_recorded(name, recorded.env_trajectory(env_id, seed, **kwargs))


@pytest.mark.parametrize(
    "name, env_id", [("reach_vector", "snac_gym/UR10Reach-v0"), ("track_vector", "snac_gym/UR10EllipseTrack-v0")]
)
def test_vector_env_is_bit_identical_to_the_recorded_one(name, env_id):
    _assert_recorded(name, recorded.vector_trajectory(env_id, 5))


def test_kinematic_engine_is_the_recorded_one():
    """θ bit for bit; e = f(θ) − x_d to rounding, since f(θ) is the compiled chain's (snac_gym/kernels/chain.py),
    whose sums run in another order than the NumPy arithmetic of the recording (measured: at most 2.2e-16 m)."""
    for key, value in recorded.engine_trajectory().items():
        if key.endswith("_errors"):
            np.testing.assert_allclose(value, RECORDED[key], rtol=0, atol=1e-15, err_msg=key)
        else:
            np.testing.assert_array_equal(value, RECORDED[key], err_msg=key)


def test_deprecated_backend_argument_warns_and_means_physics():
    with pytest.warns(DeprecationWarning, match="backend='kinematic' is deprecated; use physics='kinematic'"):
        env = gym.make("snac_gym/UR10EllipseTrack-v0", backend="kinematic")
    assert env.unwrapped.physics == "kinematic"
    with pytest.warns(DeprecationWarning, match="env.backend is deprecated"):
        assert env.unwrapped.backend == "kinematic"
    env.close()
    _assert_recorded("track_kinematic", recorded.env_trajectory("snac_gym/UR10EllipseTrack-v0", 8, backend="kinematic"))
    with pytest.raises(ValueError, match="give physics= only"), pytest.warns(DeprecationWarning):
        gym.make("snac_gym/UR10Reach-v0", physics="kinematic", backend="pybullet")
    with pytest.raises(ValueError, match=r"physics must be one of \('pybullet', 'kinematic', 'mujoco'\), got 'bullet'"):
        gym.make("snac_gym/UR10Reach-v0", physics="bullet")


# -- the env classes -----------------------------------------------------------------------------------------
ENV_CLASSES = [task_envs.ReachEnv, task_envs.EllipseTrackEnv, task_envs.PoseReachEnv, task_envs.PoseEllipseTrackEnv]
SECTIONS = (
    "## Description",
    "## Action Space",
    "## Observation Space",
    "## Rewards",
    "## Starting State",
    "## Episode End",
    "## Arguments",
    "## Version History",
)


@pytest.mark.parametrize("cls", ENV_CLASSES, ids=lambda c: c.__name__)
def test_env_classes_are_written_out_with_gymnasium_docstrings(cls):
    source = Path(task_envs.__file__).read_text()
    assert re.search(rf"^class {cls.__name__}\(URTaskEnv\):", source, re.M)  # findable by grep
    assert inspect.getdoc(cls) == inspect.cleandoc(cls.__doc__)
    for section in SECTIONS:
        assert section in cls.__doc__, section
    history = cls.__doc__.split("## Version History", 1)[1]
    assert "* v0 (snac-gym 0.1.0)" in history and "issue" not in cls.__doc__.lower()
    three_argument_type = re.compile(r"\btype\([^()]*,\s*\(")  # type(name, bases, namespace): a class built at run time
    assert (
        not three_argument_type.search(Path(core.__file__).read_text())
        and not three_argument_type.search(source)
        and not three_argument_type.search(Path(vector.__file__).read_text())
    )


def test_public_names_stay_importable():
    from snac_gym.envs import UR10EllipseTrackEnv, UR10ReachEnv

    assert UR10ReachEnv is task_envs.ReachEnv and UR10EllipseTrackEnv is task_envs.EllipseTrackEnv
    env = UR10ReachEnv(physics="kinematic")  # the UR10 is the classes' default robot, as in 0.1.0
    assert env.robot == "ur10" and env.task.name == "reach"
    with pytest.raises(ValueError, match="ReachEnv runs the task 'reach', got task='track'"):
        task_envs.ReachEnv(task="track")
    with pytest.raises(TypeError, match="URTaskEnv needs task="):
        core.URTaskEnv()


# -- one kinematic step -----------------------------------------------------------------------------------
def _python_steps(q0, commands, dt):
    """θₖ₊₁ = θₖ + uₖΔt with Python floats, one joint at a time: independent of NumPy."""
    q, out = [float(v) for v in q0], []
    for u in commands:
        q = [qi + float(ui) * dt for qi, ui in zip(q, u, strict=True)]
        out.append(q)
    return np.array(out)


def test_the_three_kinematic_steppers_match_an_independent_integration():
    dt, commands = 1 / 125, recorded.actions(recorded.STEPS, 6, 3) * 0.5
    kinematics = Kinematics("ur10")
    q0 = np.array(ROBOTS["ur10"].nominal_q)
    expected = _python_steps(q0, commands, dt)

    arm = KinematicArm(kinematics, dt)
    arm.reset(q0)
    single = []
    for u in commands:
        arm.apply(u)
        single.append(arm.joint_state()[0])
    np.testing.assert_array_equal(np.array(single), expected)

    env = gym.make_vec("snac_gym/UR10Reach-v0", 2, vectorization_mode="vector_entry_point")
    env.reset(seed=0, options={"q0": q0.tolist(), "target": [-0.6, 0.3, 0.4]})
    batched = []
    for u in commands:  # within the limits: the env applies them unclipped
        env.step(np.stack([u, u]))
        batched.append(env.unwrapped.episodes.q[1].copy())
    np.testing.assert_array_equal(np.array(batched), expected)
    env.close()
    # The evaluator's engine: the recorded run's θ log against the same integration of its commands.
    engine = RECORDED["engine_reach_q"][0]
    np.testing.assert_array_equal(
        engine[1:],
        _python_steps(
            engine[0],
            recorded.actions(recorded.STEPS, 6, 3)[:-1].clip(-kinematics.velocity_limits, kinematics.velocity_limits),
            dt,
        )[:],
    )


def test_one_implementation_of_the_kinematic_step():
    """No joint state is advanced by hand (``q = q + u * dt``, ``q += u * dt``): all call :func:`joint_step`."""
    root = Path(snac_gym.__file__).parent
    by_hand = re.compile(r"\b(self\.)?_?q\w*(\[[^\]]*\])?\s*(\+=|=\s*(self\.)?_?q\w*(\[[^\]]*\])?\s*\+)[^#]*\bdt\b")
    files = [*root.rglob("*.py"), *(root.parent / "baselines").rglob("*.py")]  # snac_gym/real/ included
    found = [
        f"{path.name}:{number}: {line.strip()}"
        for path in files
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if by_hand.search(line)
    ]
    assert found == []
    from snac_gym.model import kinematics  # the module itself, whose joint_step the grep above allows

    assert "np.add(q, u * dt, out=out)" in inspect.getsource(kinematics.joint_step)
    for module in ("physics/kinematic.py", "envs/vector.py", "rollout/kinematic.py", "real/emulator/arm.py"):
        assert "joint_step(" in (root / module).read_text(), module


def test_no_deprecation_warning_on_the_default_path():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        # Gymnasium's "out of date" notice (a -v1 exists), silenced by snac_gym on import: a -v0 id is not deprecated
        warnings.filterwarnings("ignore", message=V0_NOTICE, category=DeprecationWarning)
        env = gym.make("snac_gym/XArm7Reach-v0", physics="kinematic")
        env.reset(seed=0)
        env.step(np.zeros(7))
        env.close()
