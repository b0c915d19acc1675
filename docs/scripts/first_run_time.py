"""Time the README's main command on fresh clones (every kernel compiles), two revisions alternating.

Each round clones the repository at each revision into a temporary folder and runs
``python -m snac_gym.apps.cli evaluate`` there (the clone first on ``PYTHONPATH``, so that it runs with
an empty numba cache), then prints the wall time, the CPU time of the run and its phases
(docs/benchmarks.md, "The first run after an install").

    python docs/scripts/first_run_time.py 057e745 HEAD --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
COMMAND = ["-m", "snac_gym.apps.cli", "evaluate", "--workers", "2", "--no-progress",
           "--controllers", "snac,snac-hjb,lqr,rnn,svf,dls,ppo,optimal"]  # fmt: skip


def cold_run(revision: str) -> str:
    with tempfile.TemporaryDirectory() as folder:
        clone = Path(folder) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        subprocess.run(["git", "checkout", "-q", revision], cwd=clone, check=True)
        env = {**os.environ, "PYTHONPATH": str(clone)}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        subprocess.run([sys.executable, *COMMAND, "--out", str(clone / "run")], cwd=clone, env=env, check=True,
                       stdout=subprocess.DEVNULL)  # fmt: skip
        wall = time.perf_counter() - started
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        phases = json.loads((clone / "run" / "timings.json").read_text())
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return f"{revision}: {wall:.1f} s wall, {cpu:.1f} CPU s, phases {phases}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("revisions", nargs=2)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    for round_ in range(1, args.rounds + 1):
        for revision in args.revisions:
            print(f"round {round_}: {cold_run(revision)}", flush=True)


if __name__ == "__main__":
    main()
