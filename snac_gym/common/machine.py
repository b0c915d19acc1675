"""The machine a measurement ran on: its CPU, the one numba compiles for, the cores it may use and how busy it was.

A timing means little without them: the same code and command ran at about half the speed on one day's 2-core
machine as on another's (docs/benchmarks-log.md), and the CPU numba compiles for, like the libraries' versions, shapes
a result's last bits. ``snac-gym evaluate`` writes :func:`machine_info` to ``machine.json`` and one line of it
(:func:`describe_machine`) under its wall time; ``snac-gym bench`` prints that line first.
"""

from __future__ import annotations

import os
import platform
from typing import Any

__all__ = ["cpu_model", "cpu_target", "describe_machine", "machine_info"]


def cpu_target() -> str:
    """LLVM's name of this CPU, which numba compiles the kernels for (``znver3``, ``znver4``, ``skylake-avx512``)."""
    import llvmlite.binding  # start-up time: loads LLVM, which a command that never asks needs not

    return str(llvmlite.binding.get_host_cpu_name())


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``'s, else :func:`platform.processor`), or ``"unknown"``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as file:
            for line in file:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip() or "unknown"
    except OSError:  # not Linux
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, Any]:
    """The machine now, JSON-ready: ``cpu_model``, ``cpu_target``, ``cpus`` (the cores this process may run on),
    ``load_average`` (1, 5 and 15 minutes; ``None`` where the system has none), ``python`` and ``system``.

    Taken where a measurement starts, so that the load is the one the measurement met, not the one it made."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        load: list[float] | None = [round(value, 2) for value in os.getloadavg()]
    except (AttributeError, OSError):  # Windows, or no load figures
        load = None
    return {
        "cpu_model": cpu_model(),
        "cpu_target": cpu_target(),
        "cpus": cpus,
        "load_average": load,
        "python": platform.python_version(),
        "system": platform.platform(),
    }


def describe_machine(info: dict[str, Any]) -> str:
    """One line of :func:`machine_info`: ``AMD EPYC (znver3), 2 CPUs, load average 0.71``."""
    cpus = info.get("cpus")
    cpu = f"{info.get('cpu_model', 'unknown')} ({info.get('cpu_target', 'unknown')})"
    line = f"{cpu}, {cpus} CPU{'' if cpus == 1 else 's'}"
    load = info.get("load_average")
    return line + (f", load average {load[0]:.2f}" if load else "")
