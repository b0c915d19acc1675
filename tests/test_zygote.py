"""The zygote's children (tests/_zygote.py) behave as ``python -c`` would for what the tests that use it check:
exit codes, signals, standard streams, folder, environment, a namespace of their own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from _zygote import run


def test_a_child_exits_and_writes_as_python_c_would(zygote, tmp_path):
    code = "import sys; print('out', sys.argv[1:]); sys.stderr.write('err\\n'); sys.exit(int(sys.argv[1]))"
    done = run(zygote, code, ["3", "x"], timeout=30)
    fresh = subprocess.run([sys.executable, "-c", code, "3", "x"], capture_output=True, text=True, timeout=30)
    assert (done.returncode, done.stdout, done.stderr) == (fresh.returncode, fresh.stdout, fresh.stderr)
    assert (done.returncode, done.stdout) == (3, "out ['3', 'x']\n")
    failed = run(zygote, "raise ValueError('planted')", timeout=30)
    assert failed.returncode == 1 and failed.stderr.rstrip().endswith("ValueError: planted")
    echoed = run(zygote, "import sys; print(sys.stdin.read().upper())", input="hello", timeout=30)
    assert echoed.stdout == "HELLO\n"


def test_a_child_has_the_callers_folder_environment_and_a_namespace_of_its_own(zygote, tmp_path):
    code = "import os, sys; print(os.getcwd(), os.environ['PROBE'], sys.path[0], sorted(k for k in globals()))"
    env = {**os.environ, "PROBE": "seen", "PYTHONPATH": str(tmp_path / "first")}
    done = run(zygote, code, cwd=tmp_path, env=env, timeout=30)
    folder, probe, first, names = done.stdout.split(" ", 3)
    assert (folder, probe, first) == (str(tmp_path), "seen", str(tmp_path / "first")), done.stderr
    fresh = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert names == fresh.stdout.split(" ", 3)[3]  # what a fresh interpreter has, nothing of the server's


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, -signal.SIGINT), (signal.SIGTERM, -signal.SIGTERM)])
def test_a_signal_ends_a_child_as_it_ends_a_fresh_python(zygote, signum, code):
    """Python's own SIGINT handler (a KeyboardInterrupt that, uncaught, ends the process by SIGINT) and the
    default action of the others, whatever the server does with them."""
    process = zygote.popen("import sys, time\nprint('up', flush=True)\ntime.sleep(30)")
    assert process.stdout is not None and process.stdout.readline() == "up\n"
    os.kill(process.pid, signum)
    _, err = process.communicate(timeout=30)
    assert process.returncode == code, err
    assert ("KeyboardInterrupt" in err) == (signum == signal.SIGINT)


def test_wait_times_out_while_the_child_runs_and_kill_ends_it(zygote):
    process = zygote.popen("import time; time.sleep(30)")
    started = time.monotonic()
    with pytest.raises(subprocess.TimeoutExpired):
        process.wait(timeout=0.2)
    assert process.poll() is None
    process.kill()
    assert process.wait(timeout=30) == -signal.SIGKILL and time.monotonic() - started < 10
