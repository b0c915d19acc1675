"""The collector paused for a command's imports (snac_gym/common/startup.py): every command does its work with the
collector running again and what its imports built frozen; a library call's collector is left as it was."""

from __future__ import annotations

import gc
import importlib.util
import json
import subprocess
import sys

import pytest

from snac_gym.common import startup


@pytest.fixture
def collector():
    """The collector's state restored after the test (the freeze stays: it only spares the collector work)."""
    enabled = gc.isenabled()
    yield
    startup._paused = False
    (gc.enable if enabled else gc.disable)()


def test_paused_then_imports_done_freezes_and_restarts_the_collector(collector):
    gc.enable()
    startup.pause()
    assert not gc.isenabled()
    built = [[] for _ in range(1000)]  # objects the imports would build
    frozen = gc.get_freeze_count()
    startup.imports_done()
    # the permanent generation also loses objects that other code frees meanwhile: counts are compared with a margin
    assert gc.isenabled() and gc.get_freeze_count() >= frozen + len(built) // 2
    again = gc.get_freeze_count()
    more = [[] for _ in range(1000)]
    startup.imports_done()  # a second call: nothing more is frozen
    assert gc.isenabled() and gc.get_freeze_count() < again + len(more) // 2


def test_without_a_pause_imports_done_leaves_the_collector_alone(collector):
    gc.enable()
    frozen = gc.get_freeze_count()
    extra = [[] for _ in range(1000)]
    startup.imports_done()  # a library call: train_ppo() from a script
    assert gc.isenabled() and gc.get_freeze_count() < frozen + len(extra) // 2
    gc.disable()  # the caller's own choice survives a pause and its end
    startup.pause()
    startup.imports_done()
    assert not gc.isenabled() and gc.get_freeze_count() < frozen + len(extra) // 2


#: Each command through ``main()``, as the console script runs it, with the function that does its work replaced by
#: one that records the collector's state and stops the command.
THROUGH_MAIN = r"""
import gc, json, sys, importlib
from snac_gym.apps.cli import main

class Stop(Exception):
    pass

seen = {}
for name, argv, module, function in json.loads(sys.argv[1]):
    def record(*args, _name=name, **kwargs):
        seen[_name] = [gc.isenabled(), gc.get_freeze_count()]
        raise Stop
    setattr(importlib.import_module(module), function, record)
    sys.argv = ["snac-gym", *argv]
    try:
        main()
    except (Stop, SystemExit):
        pass
    seen.setdefault(name, None)
    seen[name + " after"] = gc.isenabled()
print(json.dumps(seen))
"""


def test_every_command_works_with_the_collector_running_and_its_imports_frozen(tmp_path):
    commands = [
        ("evaluate", ["evaluate", "--samples", "1", "--controllers", "dls", "--out", str(tmp_path / "e")],
         "snac_gym.evaluation.runner", "run_evaluation"),
        ("demo", ["demo", "--task", "reach", "--controller", "dls", "--out", str(tmp_path / "d")],
         "snac_gym.apps.demo", "run_demo"),
        ("real", ["real", "--connection", "sim", "--out", str(tmp_path / "r")],
         "snac_gym.apps.real", "run_real_episode"),
        ("bench", ["bench", "--steps", "100"], "snac_gym.apps.bench", "run_env_bench"),
        ("plot", ["plot", str(tmp_path)], "snac_gym.apps.figures", "redraw_figures"),
        ("emulate-ur", ["emulate-ur"], "snac_gym.real.emulator.serve", "serve"),
    ]  # fmt: skip
    if importlib.util.find_spec("stable_baselines3") is not None:  # the rl extra: train-ppo's work needs it
        commands.append(
            ("train-ppo", ["train-ppo", "--task", "reach", "--out", str(tmp_path / "p")],
             "snac_gym.ppo.train", "TrainingRun")
        )  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-c", THROUGH_MAIN, json.dumps(commands)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    for name, *_ in commands:
        assert seen[name] is not None, f"{name}: its work function was not reached\n{done.stderr[-2000:]}"
        enabled, frozen = seen[name]
        assert enabled, f"{name} did its work with the garbage collector paused"
        assert frozen > 100_000, f"{name}: only {frozen} objects frozen after its imports"
        assert seen[name + " after"], f"{name} left the collector paused"
