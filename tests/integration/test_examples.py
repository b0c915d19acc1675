"""The scripts in examples/ run, with tiny sizes passed on the command line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"

#: Each example with arguments small enough for a smoke test, and what its output must contain.
RUNS = {
    "train_ppo.py": (["256", "16"], "final error on 3 episodes"),
    "compare_controllers.py": (["2", "out"], "summary:"),
    "record_frames.py": (["2", "frames"], "track_00125.png"),
}


def test_every_example_is_smoke_tested():
    assert sorted(path.name for path in EXAMPLES.glob("*.py")) == sorted(RUNS)


#: The examples that train with stable-baselines3 (the rl extra).
NEEDS_RL = {"train_ppo.py"}


@pytest.mark.slow(seconds=3)
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.rl) if n in NEEDS_RL else n for n in sorted(RUNS)])
def test_example_runs(name: str, tmp_path: Path):
    args, expected = RUNS[name]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
        "MPLBACKEND": "Agg",
        "OMP_NUM_THREADS": "1",
    }
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        cwd=tmp_path,
        env=env,
        text=True,
        capture_output=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    assert expected in result.stdout, result.stdout
    if name == "record_frames.py":
        assert len(list((tmp_path / "frames").glob("*.png"))) == 2
    if name == "compare_controllers.py":
        assert (tmp_path / "out" / "summary.md").is_file()
        import pandas as pd  # the example marks every controller whose success rate is below the threshold

        rates = pd.read_parquet(tmp_path / "out" / "results.parquet").groupby(["task", "controller"])["success"].mean()
        for (task, controller), rate in rates.items():
            line = next(line for line in result.stdout.splitlines() if line.split()[:2] == [task, controller])
            assert ("FAILS the task" in line) == (rate < 0.95), (task, controller, rate, line)
