"""The reports' imports, prefetched in a thread while the last phase runs: matplotlib only where the run draws."""

from __future__ import annotations

import subprocess
import sys

CHECK = """
import sys
from snac_gym.evaluation.reports.plots import prefetch_report_modules
prefetch_report_modules(plots=False).join()
print("scipy.stats" in sys.modules, "matplotlib" in sys.modules)
"""


def test_a_run_without_plots_prefetches_scipy_stats_and_never_imports_matplotlib():
    done = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "False"], done.stdout
