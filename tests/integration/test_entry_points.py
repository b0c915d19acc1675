"""A task and a robot from a package outside the tree, registered only through the entry-point groups
``snac_gym.tasks`` and ``snac_gym.robots``, and evaluated by the unchanged ``snac-gym evaluate``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest

PACKAGE = '''
"""A package outside snac-gym that adds a task and a robot through entry points."""
from snac_gym.model.robots import ROBOTS, Robot
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import ReachTask


class HighReach(ReachTask):
    """Reach a target at least 10 cm above the cuboid's floor."""

    name, label, code = "high-reach", "High reach", 91
    env_name = "HighReach"
    success_tolerance, episode_steps, horizon_s, real_horizon_s = 2e-3, 500, 4.0, 5.0

    def sample(self, kinematics, rng, space):
        high = SampleSpace(**{**space.__dict__, "low": (*space.low[:2], space.low[2] + 0.1)})
        return super().sample(kinematics, rng, high)


ARM = Robot(
    name="ur10-limited-ext",
    urdf="ur_description/urdf/ur10_joint_limited_robot.urdf",
    nominal_q=ROBOTS["ur10"].nominal_q,
    env_prefix="UR10LimitedExt",
)
'''
ENTRY_POINTS = """
[snac_gym.tasks]
high-reach = snacext:HighReach

[snac_gym.robots]
ur10-limited-ext = snacext:ARM
"""


@pytest.fixture(scope="module")
def outside(tmp_path_factory):
    """A folder on PYTHONPATH with the package ``snacext`` and its installed metadata (entry points only)."""
    root = tmp_path_factory.mktemp("site")
    (root / "snacext").mkdir()
    (root / "snacext" / "__init__.py").write_text(PACKAGE)
    info = root / "snacext-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: snacext\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(ENTRY_POINTS))
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}


def _snac_gym(*args: str, env: dict, cwd: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-c", "from snac_gym.apps.cli import main; main()", *args]
    return subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


def test_evaluate_runs_a_task_and_a_robot_registered_from_outside(outside, tmp_path):
    out = tmp_path / "run"
    result = _snac_gym(
        "evaluate", "--task", "high-reach", "--robot", "ur10-limited-ext", "--controllers", "dls,snac",
        # --effort-samples 0: the effort is matched on these 4 samples (the same matching, on the outside
        # task's samples too), not on the default 1000 drawn for it
        "--samples", "4", "--effort-samples", "0", "--workers", "2", "--out", str(out), env=outside, cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    results = pd.read_csv(out / "results.csv")
    assert set(results["task"]) == {"high-reach"} and len(results) == 8
    assert set(results["controller"]) == {"dls", "snac"}
    assert results["success"].notna().all()
    # The samples obey the outside task's own sampling rule (10 cm above the default cuboid's floor).
    samples = pd.read_csv(out / "samples.csv")
    from snac_gym.model.kinematics import Kinematics
    from snac_gym.sampling import SampleSpace

    floor = SampleSpace.for_robot(Kinematics("ur10")).low[2]
    assert (samples["target_2"] >= floor + 0.1 - 1e-9).all()
    assert "High reach" in (out / "summary.md").read_text()


def test_the_help_lists_what_is_registered(outside, tmp_path):
    for command in ("evaluate", "demo"):
        result = _snac_gym(command, "--help", env={**outside, "COLUMNS": "400"}, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
        assert "ur10-limited-ext" in result.stdout and "high-reach" in result.stdout


def test_the_gym_ids_of_an_outside_task_and_robot_exist(outside, tmp_path):
    code = (
        "import gymnasium as gym, snac_gym; "
        "env = gym.make('snac_gym/UR10LimitedExtHighReach-v0'); "
        "print(type(env.unwrapped).__name__, env.unwrapped.task.name, env.unwrapped.kinematics.robot)"
    )
    result = subprocess.run([sys.executable, "-c", code], env=outside, cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split() == ["URTaskEnv", "high-reach", "ur10-limited-ext"]


@pytest.mark.parametrize(
    ("group", "lookup", "message"),
    [
        (
            "snac_gym.robots",
            "from snac_gym.model.robots import get_robot; get_robot('bad')",
            "entry point bad = 'badext:ARM' (snac_gym.robots) gives str, not a snac_gym.model.robots.Robot",
        ),
        (
            "snac_gym.tasks",
            "from snac_gym.tasks import get_task; get_task('bad')",
            "entry point bad = 'badext:ARM' (snac_gym.tasks): task str does not set ['name', 'label', 'code'",
        ),
    ],
)
def test_a_broken_entry_point_is_named(tmp_path, group, lookup, message):
    """An entry point whose object is not a robot (a task) is refused, naming the entry point."""
    (tmp_path / "badext.py").write_text("ARM = 'not a robot'\n")
    info = tmp_path / "badext-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: badext\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{group}]\nbad = badext:ARM\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    result = subprocess.run([sys.executable, "-c", lookup], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 1
    assert message in result.stderr
