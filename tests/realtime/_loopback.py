"""The loopback address for this test process's emulated UR controller, and the priority it runs at.

ur_rtde reaches a controller on the standard ports only (30004, 29999, 30002), so two test
processes (pytest-xdist workers) that run an emulator at the same time cannot share an address.
Each worker takes its own: Linux answers the whole 127.0.0.0/8 on the loopback interface.
"""

from __future__ import annotations

import os
import re


def emulator_host() -> str:
    """127.0.0.1 in a plain pytest run; 127.0.0.(10 + n) in xdist worker ``gw<n>``."""
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    return f"127.0.0.{10 + int(worker.group(1))}" if worker else "127.0.0.1"


#: ``SCHED_FIFO`` priority of every emulated controller here. A real UR controller is a computer of its own that
#: keeps its 125 Hz cycle whatever the host does; the emulated one shares this host's cores with the code under test,
#: the other workers' runs and anything else the machine runs, and at normal priority a busy host starved its cycle
#: (its state's timestamp stood still and the host's stale-state rule stopped runs with nothing wrong in the host's
#: code). Where the right to set it is missing (not root, no ``CAP_SYS_NICE``) it runs at normal priority and says so
#: in its events. The host's side, the code under test, stays at normal priority.
EMULATOR_PRIORITY = 20
