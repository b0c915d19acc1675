"""``snac-gym bench``: what it prints is its table alone."""

from __future__ import annotations

import os

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


def test_quiet_output_silences_the_descriptors_c_code_writes_to_under_a_capture(capfd):
    """C code writes to descriptors 1 and 2 whatever ``sys.stdout`` is: under pytest's capture it has no usable
    ``fileno()``, and the old ``quiet_output`` silenced nothing there."""
    from snac_gym.common._quiet import quiet_output

    print("before", flush=True)
    with quiet_output():
        os.write(1, b"from C, on stdout\n")
        os.write(2, b"from C, on stderr\n")
    print("after", flush=True)
    assert capfd.readouterr() == ("before\nafter\n", "")
