import atexit
import gc
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the envs)
from snac_gym.kernels.compiled import cached_on_disk
from snac_gym.model.kinematics import Kinematics

# The project's caches (snac_gym/common/cache_dir.py) in this test process: a fresh folder, so that no test reads
# rows another run left in the user's cache, and the suite writes nothing there. A pytest-xdist worker starts with its
# controller's folder in the environment; the visual meshes' OBJ copies (snac_gym/physics/meshes.py, named by
# content) stay shared with it, so that each arm's are written once a run, not once a worker.
_controller_cache = os.environ.get("SNAC_GYM_CACHE_DIR") if os.environ.get("PYTEST_XDIST_WORKER") else None
os.environ["SNAC_GYM_CACHE_DIR"] = tempfile.mkdtemp(prefix="snac-gym-test-cache-")
if _controller_cache and os.path.isdir(_controller_cache):
    os.makedirs(os.path.join(_controller_cache, "meshes"), exist_ok=True)
    os.symlink(os.path.join(_controller_cache, "meshes"), os.path.join(os.environ["SNAC_GYM_CACHE_DIR"], "meshes"))
# Removed when this process ends (the controller's last, after its workers): otherwise every run leaves one a process.
atexit.register(shutil.rmtree, os.environ["SNAC_GYM_CACHE_DIR"], ignore_errors=True)
# Stable-Baselines3 makes a log folder for every learn() without a logger of its own (an empty /tmp/SB3-<time> when
# nothing is logged): in this process's cache folder, removed with it, not in the machine's temporary folder (the
# CLI's train-ppo gives its runs their own logger).
os.environ["SB3_LOGDIR"] = os.path.join(os.environ["SNAC_GYM_CACHE_DIR"], "sb3-logs")
# The calibration cache off: a test that compares two runs' knobs (other workers, fewer samples) must match
# them anew, or it would compare a knob with itself. tests/evaluation/effort/test_effort_cache.py turns it on.
os.environ["SNAC_GYM_CALIBRATION_CACHE"] = "0"
# The sample cache off too: a test that compares samples drawn two ways (other workers, other chunks) must draw both.
# tests/evaluation/test_sample_cache.py turns it on.
os.environ["SNAC_GYM_SAMPLE_CACHE"] = "0"


#: Why a test marked ``rl`` is skipped where torch or stable-baselines3 is missing.
RL_SKIP_REASON = (
    "needs the rl extra (torch, stable-baselines3), not installed: the Python 3.12 and 3.13 variants of the "
    "README's test command leave it out (PyPI has only multi-GB CUDA builds of torch there)"
)


#: How a run stops when its host fell behind (a stalled loop, missed deadlines, a ur_rtde client or the
#: emulated controller, both processes of this host, not scheduled in time): on a shared machine that
#: is the machine, not the code. A real-time test that fails with one of these is run again, up to
#: HOST_TIMING_RERUNS times (pytest-rerunfailures); any other failure, or one more, stands.
HOST_TIMING_STOPS = [
    "control loop stalled",
    "control loop missed its",
    "ur_rtde did not return from",
    "stale joint state: the controller's timestamp stayed",
    # ur_rtde's own 5 s wait for the emulated controller's script, on a host too busy to schedule it
    "Failed to start control script, before timeout",
    # the controller's 40 ms watchdog ended the script, so that every later speedJ was refused: for 5 periods no
    # command of the host reached it (a fresh clone's CI, the UR5e track test: its loop's longest period 35.5 ms,
    # the emulated controller and the ur_rtde client on the same two cores; the suite passed twice right after)
    "rejected speedJ",
]
#: Reruns of a real-time test after a host-timing stop. One was not enough on a 2-core host with slow spells: a
#: fresh clone's CI failed the UR5e track test twice in a row for missed 8 ms deadlines (3 of 25 periods late),
#: with nothing else running, while the same code passed the run before and after.
HOST_TIMING_RERUNS = 2


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip the tests marked ``rl`` when torch or stable-baselines3 is not installed, saying why; give
    each ``realtime`` test :data:`HOST_TIMING_RERUNS` reruns after a host-timing stop."""
    # Long work first, so that the parallel workers finish together (pytest-xdist's worksteal hands
    # each worker a contiguous share and lets an idle one take the tail of another's): the real-time
    # tests by their marker's ``seconds``, the others by module, heaviest first (the ``seconds`` of
    # its ``slow`` tests), each module's tests kept together, as its fixtures are shared.
    module_seconds: dict[str, float] = {}
    for item in items:
        module_seconds[item.path] = module_seconds.get(item.path, 0.0) + _seconds(item, "slow")
    items.sort(key=lambda item: -(_seconds(item, "realtime") or module_seconds[item.path]))
    if config.pluginmanager.hasplugin("rerunfailures"):
        for item in items:
            if "realtime" in item.keywords and item.get_closest_marker("flaky") is None:
                item.add_marker(pytest.mark.flaky(reruns=HOST_TIMING_RERUNS, only_rerun=HOST_TIMING_STOPS))
    if all(importlib.util.find_spec(name) is not None for name in ("torch", "stable_baselines3")):
        return
    skip = pytest.mark.skip(reason=RL_SKIP_REASON)
    for item in items:
        if "rl" in item.keywords:
            item.add_marker(skip)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Freeze what collection built (every test module, the project and its dependencies): the garbage collector's
    full passes skip those objects for the rest of the run, as the console script's after its imports
    (:mod:`snac_gym.common.startup`). Runs where tests are collected: each pytest-xdist worker, or a plain run."""
    gc.freeze()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None):
    """After a test module's last test here, its fixtures torn down: collect its garbage, then freeze what is left
    (what the tests imported later, torch, MuJoCo, Ray; the session's fixtures; caches). Otherwise each full pass
    of the collector walks all of that again, and the passes took a twentieth of a worker's CPU."""
    yield
    if nextitem is None or nextitem.module is not item.module:
        gc.collect()
        gc.freeze()


def _seconds(item: pytest.Item, name: str) -> float:
    """The ``seconds`` hint of the item's ``name`` marker (``realtime`` or ``slow``), else 0."""
    marker = item.get_closest_marker(name)
    return float(marker.kwargs.get("seconds", 0.0)) if marker is not None else 0.0


def pytest_configure(config: pytest.Config) -> None:
    """One torch thread for the tests that train networks, as ``train-ppo`` uses: with two OpenMP
    threads on two busy cores, SAC's 200 updates of a 32×32 network in tests/envs/test_goal.py took 52 s
    instead of 4.6 s (both threads spin while the other test process or a worker holds a core).
    Set through OpenMP's variable, read when torch loads, so that a test process imports torch (1.4 s)
    only if one of its tests needs it; NumPy's BLAS, loaded already, keeps its threads.

    Bytecode is cached even where ``PYTHONDONTWRITEBYTECODE`` is set (as on the project's machines):
    the suite starts some 80 Python processes (the CLI, evaluator workers, emulated controllers),
    and without the cache each one compiles the project's sources again (0.2 s for the evaluator's
    imports), and each pytest worker rewrites every test module's asserts anew. The cache goes to
    the usual ``__pycache__/`` folders, which git ignores; installed packages have theirs already."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # for the workers and every subprocess
    sys.dont_write_bytecode = False


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the numba kernels before any test, where their cache is missing or older than their source.

    On a fresh clone the kernels compile once either way (1-2 s each); done here, no compile lands
    inside a test with a deadline, and a kernel that fails to compile is reported once. It is the
    evaluator's own start-up, two workers sharing the compiles
    (:func:`~snac_gym.kernels.compiled.warm_up_shared`), in a process of its own, before pytest-xdist starts
    its workers (its ``sessionstart`` runs last).
    """
    if hasattr(session.config, "workerinput"):
        return  # a pytest-xdist worker: the controller did it
    _ROOT_BEFORE.update(os.listdir(_ROOT))
    if cached_on_disk():
        return  # nothing to compile
    code = (
        "from snac_gym.evaluation.execution.executors import ProcessExecutor; ProcessExecutor(2).close(); "
        "from snac_gym.kernels.compiled import warm_up; warm_up()"  # the modules the workers leave to their callers
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if done.returncode != 0:  # every test that calls a kernel would fail the same way
        raise pytest.UsageError(f"compiling the numba kernels failed:\n{done.stderr}")


#: The checkout's top folder, and what it held as the session began: a test that leaves something there (a command run
#: with a relative ``--out`` from the repository) fails the session, which names it.
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_ROOT_BEFORE: set[str] = set()


def left_in_the_checkout(before: set[str], root: str = _ROOT) -> list[str]:
    """What is in ``root`` that was not in ``before``, unless git ignores all of it (a docs build's ``build/``, pytest's
    and Hypothesis' caches); an empty folder counts. [] outside a git checkout (an unpacked sdist), where nothing
    says what belongs."""
    new = sorted(set(os.listdir(root)) - before)
    if not new or not os.path.isdir(os.path.join(root, ".git")):
        return []
    status = subprocess.run(
        ["git", "status", "--porcelain", "--ignored", "--untracked-files=all", "--", *new],
        cwd=root,
        capture_output=True,
        text=True,
    ).stdout.splitlines()
    ignored = {line[3:].split("/")[0] for line in status if line.startswith("!! ")}
    untracked = {line[3:].split("/")[0] for line in status if not line.startswith("!! ")}
    return [name for name in new if name in untracked or name not in ignored]


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Fail the session if its tests left a file or folder in the checkout's top folder, naming it."""
    if hasattr(session.config, "workerinput") or not _ROOT_BEFORE:
        return
    left = left_in_the_checkout(_ROOT_BEFORE)
    if left:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            where = f"{', '.join(left)} in {_ROOT}"
            reporter.write_line("")  # after the progress line, which has no newline yet
            reporter.write_sep("=", f"the tests left {where}: a test wrote outside its tmp_path", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def once_per_session(tmp_path_factory: pytest.TempPathFactory, name: str, compute):
    """``compute()``'s value (JSON-serialisable), computed once per test session: by the one process of a
    plain run, or by the first pytest-xdist worker to ask, the others reading what it wrote.

    For a module fixture whose work is costly (a docs build, a batch of subprocesses): pytest-xdist's
    ``worksteal`` may spread one module's tests over both workers, and each worker would run the module
    fixture anew. The workers of a session share the parent of their temporary folders (as pytest-xdist's
    docs suggest); a lock there makes the others wait for the first. An exception (a skip, a failure) in
    ``compute`` stores nothing: the next worker to ask computes again, and fails or skips the same way.
    """
    try:
        import fcntl
    except ImportError:  # not POSIX: each worker computes its own
        return compute()
    import json

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, above each worker's popen-gw<N>
    stored = root / f"once-{name}.json"
    with open(root / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if stored.is_file():
            return json.loads(stored.read_text(encoding="utf-8"))
        value = compute()
        stored.write_text(json.dumps(value), encoding="utf-8")
        return value


@pytest.fixture(scope="session")
def once(tmp_path_factory):
    """:func:`once_per_session` of this session, for tests in any folder: ``once(name, compute)``."""
    return lambda name, compute: once_per_session(tmp_path_factory, name, compute)


@pytest.fixture(scope="session")
def ur10() -> Kinematics:
    return Kinematics("ur10")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture(scope="module")
def reach_env():
    """The default reach env, shared by a test module (each test resets it)."""
    env = gym.make("snac_gym/UR10Reach-v0")
    yield env
    env.close()


@pytest.fixture(scope="module")
def track_env():
    """The default tracking env, shared by a test module (each test resets it)."""
    env = gym.make("snac_gym/UR10EllipseTrack-v0")
    yield env
    env.close()


@pytest.fixture(scope="module")
def pose_tasks():
    """The pose tasks registered for the requesting module only: the other modules see the paper's two."""
    from snac_gym.envs import register_pose_envs
    from snac_gym.tasks import TASKS
    from snac_gym.tasks.pose import POSE_TASKS

    register_pose_envs()
    yield
    for task in POSE_TASKS:
        TASKS.pop(task.name, None)
        snac_gym.envs.unregister_envs(task=task.name)


@pytest.fixture
def timing_rules_off(monkeypatch) -> None:
    """The ``real`` command's safety limits without their timing rules: the simulated arm is not paced,
    and a busy host (the other test process, a writer process starting) must not stop an episode
    before the fault under test."""
    from functools import partial

    import snac_gym.real

    limits = partial(snac_gym.real.SafetyLimits, max_period=10.0, deadline_slack=10.0)
    monkeypatch.setattr(snac_gym.real, "SafetyLimits", limits)


@pytest.fixture
def reference_job(tmp_path):
    """Three reach samples' reference over 150 steps, cached in a fresh folder (the reference cache's tests)."""
    from snac_gym.evaluation.reference.optimum import OptimalJob  # the evaluator: only these tests need it
    from snac_gym.evaluation.samples import generate_samples

    from snac_gym.model.kinematics import shared_kinematics
    from snac_gym.sampling import SampleSpace

    ur10 = shared_kinematics("ur10")
    samples = tuple(generate_samples(ur10, SampleSpace.for_robot(ur10), 0, "reach", [0, 1, 2]))
    return OptimalJob("reach", samples, (0, 1, 2), steps=150, dt=1 / 125, cache_dir=str(tmp_path / "cache"))


@pytest.fixture
def counted_solves(monkeypatch) -> list[int]:
    """The sizes of the reference jobs solved from here on (not read from the cache)."""
    from snac_gym.evaluation.reference import optimum

    solved: list[int] = []
    original = optimum._solve_job

    def solve(job):
        solved.append(len(job.samples))
        return original(job)

    monkeypatch.setattr(optimum, "_solve_job", solve)
    return solved


def tiny_ppo_config(tmp_path, task="reach", timesteps=64, normalize_obs=True):
    """The task's shipped PPO config shrunk to a run of a few seconds, written under ``tmp_path`` (its path);
    ``normalize_obs``: the frozen-normalisation path of the policy file too."""
    import json

    from snac_gym.ppo.config import default_config_path, load_config  # the rl side: only the PPO tests need it

    config = load_config(default_config_path(task))
    config.update(timesteps=timesteps)
    config["vec_env"].update(n_envs=2, kind="dummy")
    config["ppo"].update(n_steps=16, batch_size=32, n_epochs=1, net_arch={"pi": [8, 8], "vf": [8, 8]})
    config["evaluation"].update(every_timesteps=32, episodes=1, horizons_s=[0.024, 0.04])
    if normalize_obs:
        config["normalize"].update(obs=True)
    path = tmp_path / f"tiny_{task}.json"
    path.write_text(json.dumps(config))
    return path


@pytest.fixture(scope="session")
def tiny_ppo():
    """:func:`tiny_ppo_config`, for tests in any folder."""
    return tiny_ppo_config


@pytest.fixture(autouse=True)
def _policy_registry_restored():
    """The controller registry as each test found it: a controller a test registers is gone after it, so the
    tests that read the registry (the README's controller table) see the package's own, whatever ran before."""
    from snac_gym.policies import registry  # the registry's own dicts, restored in place

    builtin, factories = dict(registry._BUILTIN), dict(registry._FACTORIES)
    yield
    registry._BUILTIN.clear()
    registry._BUILTIN.update(builtin)
    registry._FACTORIES.clear()
    registry._FACTORIES.update(factories)
