"""The loopback address for this test process's emulated UR controller.

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
