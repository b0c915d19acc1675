"""The machine a measurement ran on: what ``snac-gym evaluate`` writes to ``machine.json`` and under its wall time,
and what ``snac-gym bench`` prints first."""

from __future__ import annotations

import json
import os
from importlib.metadata import version

import llvmlite.binding
import numpy as np
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation

from snac_gym.common import machine
from snac_gym.common.machine import describe_machine, machine_info


def test_the_machine_is_this_one():
    info = machine_info()
    assert info["cpu_target"] == llvmlite.binding.get_host_cpu_name()  # what numba compiles the kernels for
    if hasattr(os, "sched_getaffinity"):
        assert info["cpus"] == len(os.sched_getaffinity(0))  # the cores this process may use, not the host's count
    load = info["load_average"]
    assert load is None or (len(load) == 3 and all(value >= 0 for value in load))
    assert isinstance(info["cpu_model"], str) and info["cpu_model"]
    json.dumps(info)  # written as JSON


@pytest.mark.parametrize(
    ("info", "line"),
    [
        ({"cpu_model": "AMD EPYC", "cpu_target": "znver3", "cpus": 2, "load_average": [0.714, 1.0, 1.0]},
         "AMD EPYC (znver3), 2 CPUs, load average 0.71"),
        ({"cpu_model": "Apple M2", "cpu_target": "apple-m2", "cpus": 1, "load_average": None},
         "Apple M2 (apple-m2), 1 CPU"),
        ({"cpus": 4}, "unknown (unknown), 4 CPUs"),
    ],
)  # fmt: skip
def test_one_line_names_the_cpu_the_cores_and_the_load(info, line):
    assert describe_machine(info) == line


def test_an_evaluation_records_the_machine_and_the_load_it_met_at_its_start(tmp_path, monkeypatch):
    """The load average is read once, as the run starts: a run's own workers would otherwise raise the figure that
    says how busy the machine was before it."""
    calls = []
    out = tmp_path / "run"

    def load_average():
        calls.append((out / "run.json").exists())  # written once the samples are drawn
        return (3.25 + len(calls), 2.0, 1.0)  # each call reads higher, as a run's own load would

    monkeypatch.setattr(machine.os, "getloadavg", load_average)
    config = EvaluationConfig(out=out, samples=2, controllers=("snac",), effort_samples=0,
                              horizons={"reach": 0.2, "track": 0.2}, progress=False, plots=False)  # fmt: skip
    run_evaluation(config)
    recorded = json.loads((config.out / "machine.json").read_text())
    assert recorded["load_average"] == [4.25, 2.0, 1.0] and calls == [False]  # once, before the run began
    assert recorded["cpu_target"] == llvmlite.binding.get_host_cpu_name()
    assert recorded["versions"]["numpy"] == np.__version__ and recorded["versions"]["snac-gym"] == version("snac-gym")
    wall = next(line for line in (config.out / "summary.md").read_text().splitlines() if line.startswith("Wall time"))
    assert f"Machine: {describe_machine(recorded)} at the start (`machine.json`)." in wall
    assert "load average 4.25" in wall
