"""The compiled kernels' first call: a stop signal that comes while numba compiles is not lost."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from snac_gym.compiled import _with_stop_signals_held

pytestmark = pytest.mark.skipif(os.name != "posix", reason="POSIX signals")


def test_a_signal_during_the_held_call_is_raised_to_the_previous_handler_once_it_returns():
    calls: list[str] = []

    def interrupt(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)

    def work(value):
        os.kill(os.getpid(), signal.SIGTERM)  # arrives while the call runs
        calls.append("finished")
        return value * 2

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            _with_stop_signals_held(work, (21,))
        assert calls == ["finished"]  # the call ran to its end first
        assert signal.getsignal(signal.SIGTERM) is interrupt  # and the handler is back
        assert _with_stop_signals_held(lambda: 7, ()) == 7  # nothing pending: the result comes back
    finally:
        signal.signal(signal.SIGTERM, previous)


DRIVER = r"""
import os, signal, sys, threading, time
import numpy as np

def interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)

signal.signal(signal.SIGTERM, interrupt)
import snac_gym.chain_kernel  # numba imported and the kernel defined, not compiled yet
from snac_gym.kinematics import Kinematics
chain = Kinematics("ur10")._chain
configurations = np.zeros((2, 6))
if sys.argv[1] == "read-only":  # compile once now, then again for read-only arrays: a second signature
    chain.forward_and_jacobian(configurations)
    configurations.setflags(write=False)
threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGTERM)).start()
started = time.perf_counter()
try:
    x, _ = chain.forward_and_jacobian(configurations)
except KeyboardInterrupt as exc:
    print("interrupted", exc, round(time.perf_counter() - started, 2), flush=True)
    sys.exit(143)
print("not interrupted", round(time.perf_counter() - started, 2))
"""


@pytest.mark.parametrize("arrays", ["writable", "read-only"])
def test_sigterm_while_a_kernel_compiles_ends_the_program_after_the_compile(tmp_path, arrays):
    # An empty cache folder: the kernel compiles in this child (seconds), and the signal comes meanwhile.
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", DRIVER, arrays], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 143, done.stdout + done.stderr
    assert done.stdout.startswith("interrupted SIGTERM"), done.stdout
    assert "Exception ignored" not in done.stderr, done.stderr
    assert float(done.stdout.split()[-1]) > 0.3  # raised after the compile, not at the signal
    assert len(list(tmp_path.rglob("*chain_forward_and_jacobian*.nbc"))) == (2 if arrays == "read-only" else 1)


@pytest.mark.parametrize("controller", ["lqr", "svf", "snac-hjb", "dls", "snac"])
@pytest.mark.parametrize("task", ["reach", "track"])
def test_after_the_warm_up_no_controller_step_compiles_anything(controller, task):
    """What ``snac-gym real`` relies on: every kernel a controller calls has the types of its warm-up example."""
    import gymnasium as gym

    from snac_gym.compiled import _KERNELS, POLICY_KERNEL_MODULES, warm_up
    from snac_gym.policies import make_policy

    warm_up(POLICY_KERNEL_MODULES)
    compiled = {k.__name__: len(k.dispatcher.signatures) for k in _KERNELS}
    env = gym.make(f"snac_gym/UR10{'Reach' if task == 'reach' else 'EllipseTrack'}-v0", physics="kinematic")
    policy = make_policy(controller, env.unwrapped)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(policy.act(obs))
    env.close()
    assert {k.__name__: len(k.dispatcher.signatures) for k in _KERNELS} == compiled
