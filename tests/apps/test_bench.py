"""``snac-gym bench``: what it prints is its table alone."""

from __future__ import annotations

import pytest

from snac_gym.apps.bench import format_env_bench, run_env_bench


def test_panda_gyms_env_prints_nothing_of_its_own_on_stdout(capfd):
    """PyBullet writes the options panda-gym connects with ("argv[0]=--background_color_red=...") to the process's
    stdout, before the table: ``snac-gym bench > table.txt`` got three lines of them."""
    pytest.importorskip("panda_gym")
    results = run_env_bench(steps=100, physics=())
    out, _ = capfd.readouterr()
    assert out == "", out
    assert list(results) == ["PandaReachJoints-v3 (panda-gym)"] and results["PandaReachJoints-v3 (panda-gym)"]
    assert format_env_bench(results).splitlines()[0].split() == [
        "env",
        "steps/s",
        "control",
        "dt",
        "real-time",
        "factor",
    ]
