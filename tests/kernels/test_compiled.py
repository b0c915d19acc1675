"""The compiled kernels' first call: a stop signal that comes while numba compiles is not lost."""

from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys

import pytest

from snac_gym.kernels.compiled import _with_stop_signals_held

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


WORKER_DRIVER = r"""
import os, signal, sys
from snac_gym.kernels.compiled import _with_stop_signals_held

signal.signal(signal.SIGINT, signal.SIG_IGN)  # as an evaluator worker: Ctrl-C is the parent's, SIGTERM ends it
signal.signal(signal.SIGTERM, signal.SIG_DFL)

def compile_like():
    os.kill(os.getpid(), signal.SIGINT)  # the terminal's Ctrl-C, to the whole group
    os.kill(os.getpid(), signal.SIGTERM)  # then the parent ending its workers
    return "compiled"

print(_with_stop_signals_held(compile_like, ()), flush=True)
print("survived", flush=True)
"""


def test_a_worker_that_ignores_sigint_still_dies_of_the_sigterm_that_came_after_it_during_a_compile():
    done = subprocess.run([sys.executable, "-c", WORKER_DRIVER], capture_output=True, text=True, timeout=60)
    assert done.returncode == -signal.SIGTERM, done.stdout + done.stderr
    assert "survived" not in done.stdout


DRIVER = r"""
import os, signal, sys, threading, time
import numpy as np

def interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)

signal.signal(signal.SIGTERM, interrupt)
import snac_gym.kernels.chain  # numba imported and the kernel defined, not compiled yet
from snac_gym.model.kinematics import Kinematics
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


@pytest.mark.slow(seconds=3)
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

    from snac_gym.kernels.compiled import _KERNELS, POLICY_KERNEL_MODULES, warm_up
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


def test_after_the_warm_up_an_evaluation_compiles_nothing(tmp_path, monkeypatch):
    """What an evaluator worker relies on (it warms up every module when it starts): the rollouts, the
    metrics and the optimum call each kernel with the types of one of its warm-up examples, read-only
    arrays too. Every call's types are recorded, so what other tests compiled earlier does not matter."""
    import numba
    from snac_gym.evaluation.run_config import EvaluationConfig
    from snac_gym.evaluation.runner import run_evaluation

    from snac_gym.kernels.compiled import _KERNELS, KERNEL_MODULES, Kernel

    for module in KERNEL_MODULES:
        importlib.import_module(module)
    warmed = {}
    for compiled in _KERNELS:
        examples = compiled.example()
        examples = examples if isinstance(examples, list) else [examples]
        warmed[compiled.__name__] = {tuple(map(numba.typeof, arguments)) for arguments in examples}
    called: dict[str, set] = {}
    call = Kernel.__call__

    def recording(self, *args):
        called.setdefault(self.__name__, set()).add(tuple(map(numba.typeof, args)))
        return call(self, *args)

    monkeypatch.setattr(Kernel, "__call__", recording)
    controllers = ("snac", "snac-hjb", "lqr", "rnn", "svf", "dls", "optimal")
    config = EvaluationConfig(
        out=tmp_path / "run", samples=2, workers=1, controllers=controllers, horizons={"reach": 1.0, "track": 1.0},
        effort_samples=0, progress=False, plots=False,
    )  # fmt: skip
    run_evaluation(config)
    assert {"chain_forward_and_jacobian", "thin_svd", "add_jacobian_blocks"} <= called.keys()
    assert called.keys() <= warmed.keys()  # a kernel left out of the warm-up (warm=False) is one no run calls
    assert {name: types - warmed[name] for name, types in called.items() if types - warmed[name]} == {}


def test_a_run_without_the_reference_calls_no_kernel_its_workers_leave_out(tmp_path, monkeypatch):
    """An evaluator's workers compile the reference's kernels only for a run that has it
    (:func:`~snac_gym.kernels.compiled.evaluator_kernel_modules`): a run of the default controllers, matching their
    knobs, calls none of them (else each worker would compile one at its first call), and every kernel it calls is of a
    module its workers warm up."""
    from snac_gym.evaluation.run_config import EvaluationConfig
    from snac_gym.evaluation.runner import run_evaluation

    from snac_gym.control import lower_bounds
    from snac_gym.kernels.compiled import LATE_KERNEL_MODULES, Kernel, evaluator_kernel_modules

    called: set[str] = set()
    call, bound = Kernel.__call__, lower_bounds.relaxation_kernel

    def recording(self, *args):
        called.add(self.__wrapped__.__module__)
        return call(self, *args)

    def built():  # the lower bound's kernel is built on first use, not a Kernel
        called.add("snac_gym.kernels.relaxation")
        return bound()

    monkeypatch.setattr(Kernel, "__call__", recording)
    monkeypatch.setattr(lower_bounds, "relaxation_kernel", built)
    config = EvaluationConfig(
        out=tmp_path / "run", samples=2, effort_samples=3, workers=1, horizons={"reach": 1.0, "track": 1.0},
        progress=False, plots=False,
    )  # fmt: skip
    run_evaluation(config)
    assert {"snac_gym.kernels.chain", "snac_gym.kernels.hjb"} <= called  # what it records is what the run calls
    assert called <= set(evaluator_kernel_modules(reference=False))
    assert set(evaluator_kernel_modules(reference=False)).isdisjoint(LATE_KERNEL_MODULES)
    assert set(evaluator_kernel_modules(reference=True)) >= set(LATE_KERNEL_MODULES)


SHARED_DRIVER = r"""
import json, multiprocessing, sys
from snac_gym.kernels.compiled import _KERNELS, warm_up_shared

MODULES = ("snac_gym.kernels.hjb", "snac_gym.kernels.metrics")  # neither late: each process waits for the other

def work(locks, barrier, queue):
    barrier.wait()  # both start together, as the evaluator's workers do
    taken = warm_up_shared(locks, MODULES)
    compiled = sorted({k.__wrapped__.__module__ for k in _KERNELS if sum(k.dispatcher.stats.cache_misses.values())})
    loaded = sorted({k.__wrapped__.__module__ for k in _KERNELS if sum(k.dispatcher.stats.cache_hits.values())})
    queue.put({"taken": taken, "compiled": compiled, "loaded": loaded})

context = multiprocessing.get_context(sys.argv[1])
locks, barrier, queue = [context.Lock() for _ in MODULES], context.Barrier(2), context.Queue()
workers = [context.Process(target=work, args=(locks, barrier, queue)) for _ in range(2)]
for worker in workers:
    worker.start()
print(json.dumps([queue.get(timeout=120) for _ in workers]))
for worker in workers:
    worker.join()
"""


@pytest.mark.slow(seconds=3)
def test_processes_that_share_the_compile_locks_compile_each_kernel_module_once(tmp_path):
    import json

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}  # an empty cache: every kernel compiles
    done = subprocess.run(
        [sys.executable, "-c", SHARED_DRIVER, "fork"], capture_output=True, text=True, timeout=180, env=env
    )
    assert done.returncode == 0, done.stderr
    reports = json.loads(done.stdout)
    modules = {"snac_gym.kernels.hjb", "snac_gym.kernels.metrics"}
    compiled = [module for report in reports for module in report["compiled"]]
    assert sorted(compiled) == sorted(modules)  # each module compiled by one process only
    for report in reports:
        assert set(report["compiled"]) <= set(report["taken"])
        assert set(report["compiled"]) | set(report["loaded"]) == modules  # the rest came from the other's cache


def test_a_compile_lock_never_released_delays_the_warm_up_and_does_not_block_it(monkeypatch):
    import threading

    import snac_gym.kernels.compiled as compiled

    monkeypatch.setattr(compiled, "_SHARED_COMPILE_WAIT_S", 0.2)
    held = threading.Lock()
    held.acquire()  # as by a process that died while compiling
    assert compiled.warm_up_shared([held], ("snac_gym.kernels.trajopt",)) == []
    with pytest.raises(ValueError, match="one lock per module"):
        compiled.warm_up_shared([], ("snac_gym.kernels.trajopt",))


def test_cached_on_disk_says_whether_numba_holds_every_kernel_of_the_current_source(tmp_path, monkeypatch):
    """numba's own test of its index decides (numba 0.68 stamps an index with a hash of the source, so a file
    touched but not changed, a checkout there and back, still counts as cached); an edited source does not."""
    from snac_gym.kernels import compiled

    monkeypatch.setattr(compiled, "_KERNELS", [])  # this test's kernels only
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))  # read when the kernels are defined
    monkeypatch.syspath_prepend(str(tmp_path))
    name = f"tiny_kernels_{os.getpid()}"
    source = tmp_path / f"{name}.py"
    source.write_text(
        "from snac_gym.kernels.compiled import kernel\n\n\n"
        "@kernel(example=lambda: (2.0,))\ndef double(x):\n    return 2.0 * x\n\n\n"
        "@kernel(example=lambda: (2.0,))\ndef halve(x):\n    return 0.5 * x\n"
    )
    try:
        module = importlib.import_module(name)
        assert not compiled.cached_on_disk((name,))  # never compiled
        module.double(1.0)
        assert not compiled.cached_on_disk((name,))  # one kernel of two
        compiled.warm_up((name,))
        assert compiled.cached_on_disk((name,))
        source.write_text(source.read_text() + "\n# edited\n")
        assert not compiled.cached_on_disk((name,))  # the source changed since
        compiled.warm_up((name,))  # the process has them: nothing is written again
        assert not compiled.cached_on_disk((name,))
    finally:
        sys.modules.pop(name, None)


PRELOAD_DRIVER = r"""
import importlib, json
from snac_gym.kernels import compiled
for module in compiled.KERNEL_MODULES:
    importlib.import_module(module)
before = sorted(k.__name__ for k in compiled._KERNELS if k.dispatcher.overloads)
import snac_gym.evaluation.execution.kernel_preload  # what the evaluator's fork server imports before it forks
# any worker
misses = []
for k in compiled._KERNELS:
    k.dispatcher._compile_for_args = lambda *args, _name=k.__name__, **kwargs: misses.append(_name)
compiled.warm_up()  # what each worker's start-up calls
after = sorted(k.__name__ for k in compiled._KERNELS if k.dispatcher.overloads)
print(json.dumps({"before": before, "after": after, "misses": sorted(set(misses)),
                  "all": sorted(k.__name__ for k in compiled._KERNELS)}))
"""


HELPER_DRIVER = r"""
import sys
from snac_gym.kernels import compiled
from {kernels} import twice_shifted
print(twice_shifted(1.0), compiled.cached_on_disk(("{kernels}",)))
"""


def test_a_kernel_runs_the_helper_of_another_module_as_that_module_now_reads(tmp_path):
    # Numba stamps a cached kernel with its own file only: without stamp_with_dependencies a kernel that inlines a
    # helper of another module (the curvature kernel the chain's joint_frames) kept running the helper as compiled.
    package = tmp_path / f"kernels_{os.getpid()}"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "helpers.py").write_text(
        "from snac_gym.kernels.compiled import helper\n\n\n"
        "def shift(x):\n    return x + 1.0\n\n\nshift = helper(shift, inline=True)\n"
    )
    (package / "main.py").write_text(
        f"from snac_gym.kernels.compiled import kernel\nfrom {package.name}.helpers import shift\n\n\n"
        "@kernel(example=lambda: (2.0,))\ndef twice_shifted(x):\n    return 2.0 * shift(x)\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(tmp_path)}
    driver = HELPER_DRIVER.format(kernels=f"{package.name}.main")

    def run() -> str:
        done = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, timeout=120, env=env)
        assert done.returncode == 0, done.stderr
        return done.stdout.split()

    assert run() == ["4.0", "True"]  # compiled, then cached
    assert run() == ["4.0", "True"]  # loaded
    (package / "helpers.py").write_text((package / "helpers.py").read_text().replace("x + 1.0", "x + 100.0"))
    assert run() == ["202.0", "True"]  # the helper's module changed: compiled again, not loaded stale


def test_the_fork_server_loads_every_kernel_its_workers_call_at_start_up():
    """With the cache up to date (the session's start compiled it, conftest.py), a worker forked from
    the server starts with every kernel loaded: its warm-up loads nothing itself."""
    import json

    done = subprocess.run([sys.executable, "-c", PRELOAD_DRIVER], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["before"] == [] and report["after"] == report["all"] and len(report["all"]) >= 8
    assert report["misses"] == []


def test_a_writable_stack_reaches_the_kernels_as_a_read_only_one(monkeypatch):
    """The wrappers hand their stacks to the kernels read-only (the kinematics' cached Jacobians are), so a writable
    stack does not compile a second signature: each one costs a cold run a fraction of a second to seconds."""
    import numpy as np

    from snac_gym.control.cost import CostConvention
    from snac_gym.control.gauss_newton import gauss_newton_direction, theta_system_base
    from snac_gym.control.optimality import FrozenJacobianLQR
    from snac_gym.kernels.compiled import Kernel, read_only_view
    from snac_gym.kernels.small import eigh, svd
    from snac_gym.model.joint_goal import _resolve

    seen: dict[str, list[bool]] = {}
    call = Kernel.__call__
    stack_argument = {"add_jacobian_blocks": 1}  # its first argument is the band it writes
    no_stack = {"banded_cholesky_solve"}  # the call's own band, which it factors in place, and right-hand side

    def recording(self, *args):
        if self.__name__ not in no_stack:
            seen.setdefault(self.__name__, []).append(args[stack_argument.get(self.__name__, 0)].flags.writeable)
        return call(self, *args)

    monkeypatch.setattr(Kernel, "__call__", recording)
    rng = np.random.default_rng(0)
    jacobians = rng.normal(size=(4, 3, 6))  # writable
    svd(jacobians)
    eigh(np.einsum("kij,klj->kil", jacobians, jacobians))
    FrozenJacobianLQR(np.eye(3), np.eye(6), 3, 6).factors(jacobians)
    _resolve(jacobians, rng.normal(size=(4, 3)))
    base = theta_system_base(4, 6, 0.008, CostConvention())
    gauss_newton_direction(base, jacobians, rng.normal(size=(4, 6)), 0.008, 1.0)
    kernels = ("thin_svd", "symmetric_eigh", "frozen_lqr_factors", "damped_resolve", "add_jacobian_blocks")
    assert seen == {name: [False] for name in kernels}
    view = read_only_view(jacobians)
    assert np.shares_memory(view, jacobians) and not view.flags.writeable and jacobians.flags.writeable


ANNOUNCE_DRIVER = r"""
from snac_gym.kernels.compiled import on_first_compile
from {module} import doubled, tripled
heard = []
doubled(1.0)  # before the block: compiled or loaded, unheard either way
with on_first_compile(lambda: heard.append("compiling")):
    tripled(1.0)
    tripled(1)  # a second signature: a second compile, not a second announcement
print(len(heard))
tripled(1.5j)  # after the block: unheard
"""


def test_the_first_compile_is_announced_once_and_a_load_from_the_cache_is_not(tmp_path):
    # What makes `snac-gym demo` say that it compiles: numba's compile event, sent for a compile and not for a load.
    module = f"announced_{os.getpid()}"
    (tmp_path / f"{module}.py").write_text(
        "from snac_gym.kernels.compiled import kernel\n\n\n"
        "@kernel(example=lambda: (2.0,))\ndef doubled(x):\n    return 2.0 * x\n\n\n"
        "@kernel(example=lambda: (2.0,))\ndef tripled(x):\n    return 3.0 * x\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(tmp_path)}

    def heard() -> str:
        done = subprocess.run([sys.executable, "-c", ANNOUNCE_DRIVER.format(module=module)], capture_output=True,
                              text=True, timeout=120, env=env)  # fmt: skip
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()

    assert heard() == "1"  # an empty cache: compiled, announced once
    assert heard() == "0"  # every signature in the cache: loaded, nothing said
