"""Every command ends the same way on SIGINT, SIGTERM, SIGHUP and SIGQUIT: one line on stderr saying what
was interrupted and what was kept, exit 128 + the signal's number, and outputs that are whole (a run that
can be resumed, or one marked partial).

Each test runs ``snac-gym`` in a child process, as a user's terminal or a scheduler would, and sends the
signal to it either as soon as its handlers are in place (the command's first second, before it wrote
anything) or from inside one phase of its work (a small driver hooks the function that phase calls).
The mid-run interrupts of ``evaluate`` and ``real`` are in tests/integration/test_interrupts.py and
tests/real/test_env_faults.py.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import llvmlite.binding
import pandas as pd
import pytest

if os.name != "posix":  # pragma: no cover
    pytest.skip("POSIX signals", allow_module_level=True)

SIGNALS = ["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"]
#: Seconds a command may take to end after the signal.
EXIT_BOUND_S = 20.0

#: Runs ``snac-gym`` with argv[3:]; with a hook, sends signal argv[2] to itself at the argv[1]-th call of
#: the hooked function (module:attribute in argv[1] as "module:attr@count").
DRIVER = r"""
import importlib, os, signal, sys
hook, signame = sys.argv[1], sys.argv[2]
sys.argv = ["snac-gym", *sys.argv[3:]]
signal.signal(signal.SIGINT, signal.default_int_handler)  # a background job starts with SIGINT ignored
if hook != "-":
    target, count = hook.split("@")
    module_name, attribute = target.split(":")
    owner = importlib.import_module(module_name)
    *path, name = attribute.split(".")
    for part in path:
        owner = getattr(owner, part)
    original = getattr(owner, name)
    calls = [0]

    def hooked(*args, **kwargs):
        calls[0] += 1
        if calls[0] == int(count):
            os.kill(os.getpid(), getattr(signal, signame))
        return original(*args, **kwargs)

    setattr(owner, name, hooked)
from snac_gym.apps.cli import main
main()
"""


def _catches_stop_signals(pid: int) -> bool:
    """Whether the process has handlers for all four stop signals (its ``SigCgt`` mask)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return all(mask >> (int(getattr(signal, name)) - 1) & 1 for name in SIGNALS)


def _run(
    args: list[str],
    signame: str,
    hook: str = "-",
    cwd: Path | None = None,
    send_when: str | None = "handlers",
    timeout: float = 120.0,
    delay: float = 0.0,
) -> tuple[int, str, str]:
    """Run the driver; without a hook, send ``signame`` once the handlers are in place (or once
    ``send_when`` appears on stdout). Returns (exit code, stderr, stdout)."""
    process = subprocess.Popen(
        [sys.executable, "-c", DRIVER, hook, signame, *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        if hook == "-" and send_when == "handlers":
            deadline = time.monotonic() + 60
            while not _catches_stop_signals(process.pid) and time.monotonic() < deadline:
                time.sleep(0.005)
            # every command handles all four: which one is then sent exercises the same handler
            assert _catches_stop_signals(process.pid), "the command never caught all four stop signals"
            time.sleep(delay)
            os.kill(process.pid, getattr(signal, signame))
        elif hook == "-":
            assert process.stdout is not None
            for line in process.stdout:  # a server: once it says it serves
                if send_when in line:
                    break
            os.kill(process.pid, getattr(signal, signame))
        out, err = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    return process.returncode, err, out


#: The progress lines a demo or a plot writes on stderr as it goes (steps run, figures to draw, kernels compiling),
#: before the line that says how it ended.
PROGRESS_LINE = re.compile(
    r"^(demo|plot|real): (\d+/\d+ steps \(|drawing \d+ figures into |compiling the numerical kernels |the control loop)"
)


def _one_line(err: str) -> str:
    """The one line that says how the command ended: the last on stderr, after its progress lines only."""
    lines = [line for line in err.splitlines() if line.strip()]
    ending = [line for line in lines if not PROGRESS_LINE.match(line)]
    assert len(ending) == 1 and lines[-1] == ending[0], err
    return ending[0]


# -- the first second: nothing written, one line ------------------------------------------------------
COMMANDS = {
    "demo": ["demo", "--task", "reach", "--out", "{out}"],
    "evaluate": ["evaluate", "--out", "{out}", "--samples", "4", "--no-progress"],
    "train-ppo": ["train-ppo", "--task", "reach", "--out", "{out}"],
    "bench": ["bench", "--steps", "2000", "--no-panda"],
    "real": ["real", "--connection", "sim", "--out", "{out}", "--steps", "50"],
}


#: What each command says it kept when a signal comes in its start (its imports and option checks), besides
#: "while the command was starting: nothing was written" (a signal before its body ran).
EARLY_LINES = {
    "demo": ["nothing was written"],
    "evaluate": ["before the run started: nothing was written", "while drawing the samples: nothing to resume"],
    "train-ppo": ["nothing was trained; run the command again"],
    "bench": ["bench writes no files; the tables printed above are complete"],
    "real": ["the arm was stopped (before the episode: nothing logged)"],
}
#: Seconds after the handlers are in place: at once (in typer's start) or a little later (in the command's body).
DELAYS = {"SIGINT": 0.0, "SIGTERM": 0.4, "SIGHUP": 0.0, "SIGQUIT": 0.4}


#: Two signals per command, one sent at once (typer's start) and one later (the command's body): all four
#: go through the one handler (snac_gym/common/_signals.py), and _run asserts that the command caught all four
#: before any is sent; each signal is still sent to two commands or more, at its delay.
FIRST_SECOND_CASES = [
    ("bench", "SIGINT"), ("bench", "SIGTERM"),
    ("demo", "SIGHUP"), ("demo", "SIGQUIT"),
    ("evaluate", "SIGINT"), ("evaluate", "SIGQUIT"),
    ("real", "SIGHUP"), ("real", "SIGTERM"),
    ("train-ppo", "SIGINT"), ("train-ppo", "SIGQUIT"),
]  # fmt: skip


@pytest.mark.slow(seconds=12)
@pytest.mark.parametrize(("command", "signame"), FIRST_SECOND_CASES)
def test_a_stop_signal_in_a_commands_first_second_ends_it_with_one_line_and_nothing_written(tmp_path, command, signame):
    if command == "train-ppo":
        # Without the rl extra the command refuses at once and may be gone before the signal comes.
        pytest.importorskip("stable_baselines3")
    out = tmp_path / "out"
    args = [arg.replace("{out}", str(out)) for arg in COMMANDS[command]]
    code, err, _ = _run(args, signame, cwd=tmp_path, delay=DELAYS[signame])
    assert code == 128 + int(getattr(signal, signame)), err
    line = _one_line(err)
    kept = ["while the command was starting: nothing was written", *EARLY_LINES[command]]
    in_its_work = {
        "real": "the arm was stopped; the log so far is in",
        "demo": 'a summary marked "complete": false are in',
        "evaluate": "finished jobs are kept in",  # its sample set written: a run to resume
    }
    if command in in_its_work and in_its_work[command] in line:
        # On a quick host the command is already at work at the later delay: it keeps what it did and says where,
        # which is what it must do there (the mid-work tests check those files).
        assert line.startswith(f"interrupted by {signame}") and str(out) in line, line
        assert [p for p in out.rglob("*") if p.is_file()], line  # where it says, there is something
        return
    assert line.startswith(f"interrupted by {signame}") and any(text in line for text in kept), line
    assert not out.exists() or not [p for p in out.rglob("*") if p.is_file()], sorted(out.rglob("*"))


@pytest.mark.parametrize("signame", SIGNALS)
def test_the_emulator_ends_on_each_stop_signal_with_its_line(tmp_path, signame):
    code, err, _ = _run(["emulate-ur", "--port-base", "0"], signame, send_when="emulated UR controller")
    assert code == 128 + int(getattr(signal, signame)), err
    assert [line for line in err.splitlines() if "interrupted" in line] == [
        f"interrupted by {signame}: the emulator closed its connections; it keeps no files"
    ], err


# -- demo: a partial run is kept and marked ------------------------------------------------------------
#: Two of the four signals for the interrupts mid-work (a child process each, seconds apiece): every signal
#: goes through the one handler (snac_gym/common/_signals.py), each is sent to every command in its first second
#: above, and SIGTERM and SIGQUIT mid-work below (demo's figures, bench's tables); SIGINT is Python's own
#: KeyboardInterrupt, SIGHUP one the guard turns into one (its name must reach the line, where a lost name
#: would read "SIGINT"), and its run is the one resumed.
MID_RUN_SIGNALS = ["SIGINT", "SIGHUP"]


@pytest.mark.slow(seconds=4)
@pytest.mark.parametrize("signame", MID_RUN_SIGNALS)
def test_demo_interrupted_mid_rollout_keeps_the_steps_run_marked_partial(tmp_path, signame):
    out = tmp_path / "demo"
    hook = "snac_gym.rollout.episode:_Record.command@40"  # the 40th applied command
    code, err, _ = _run(["demo", "--task", "track", "--out", str(out)], signame, hook=hook)
    assert code == 128 + int(getattr(signal, signame)), err
    assert _one_line(err) == (
        f"interrupted by {signame}: the log of the 39 of 2500 steps run and a summary marked "
        f'"complete": false are in {out}/ (no figures)'
    )
    summary = json.loads((out / "track_snac_summary.json").read_text())
    assert summary["complete"] is False and summary["interrupted_by"] == signame
    assert summary["steps"] == 39 and summary["steps_planned"] == 2500
    log = pd.read_parquet(out / "track_snac_log.parquet")
    assert len(log) == 39 and not list(out.glob("*.png"))


@pytest.mark.slow(seconds=6)
def test_demo_interrupted_while_drawing_keeps_log_summary_and_whole_figures(tmp_path):
    out = tmp_path / "demo"
    hook = "snac_gym.apps.plots:save_figure@3"  # as the third figure is written
    code, err, _ = _run(["demo", "--task", "reach", "--steps", "200", "--out", str(out)], "SIGTERM", hook=hook)
    assert code == 143, err
    assert _one_line(err) == (
        f"interrupted by SIGTERM: the log and summary are complete in {out}/; 2 of 7 figures were drawn (each whole); "
        f"`snac-gym plot {out}/reach_snac_log.parquet` draws them all"
    )
    assert json.loads((out / "reach_snac_summary.json").read_text())["complete"] is True
    pngs = sorted(out.glob("*.png*"))
    assert [p.suffix for p in pngs] == [".png", ".png"], pngs  # no .partial left
    for png in pngs:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.read_bytes()[-8:-4] == b"IEND"


def test_real_interrupted_while_drawing_says_its_data_is_whole_and_how_many_figures_were_drawn(tmp_path):
    out = tmp_path / "real"
    hook = "snac_gym.apps.plots:save_figure@3"  # as the third figure is written, the episode over and its data too
    args = ["real", "--connection", "sim", "--steps", "50", "--out", str(out)]
    code, err, _ = _run(args, "SIGQUIT", hook=hook)
    assert code == 128 + signal.SIGQUIT, err
    assert _one_line(err) == (
        f"interrupted by SIGQUIT: the arm was stopped; the log and summary are complete in {out}/; 2 of 8 figures "
        f"were drawn (each whole); `snac-gym plot {out}/reach_snac_log.parquet` draws them all"
    )
    assert json.loads((out / "reach_snac_real.json").read_text())["timing"]["periods"] == 50
    assert len(pd.read_parquet(out / "reach_snac_log.parquet")) == 50
    assert len(list(out.glob("*.png*"))) == 2  # whole (tests/real/test_env_faults.py checks which), no .partial


def test_plot_interrupted_while_drawing_says_how_many_figures_it_drew(tmp_path):
    from snac_gym.apps.demo import run_demo

    run_demo(task="reach", controller="dls", out_dir=tmp_path / "run", steps=50, plots=False)
    log, out = tmp_path / "run" / "reach_dls_log.parquet", tmp_path / "figures"
    code, err, _ = _run(["plot", str(log), "--out", str(out)], "SIGINT", hook="snac_gym.apps.plots:save_figure@2")
    assert code == 130, err
    assert _one_line(err) == (
        f"interrupted by SIGINT: in {out}/: 1 of 5 figures were drawn (each whole); "
        f"`snac-gym plot {log}` draws them all"
    )
    assert [p.name for p in out.iterdir()] == ["reach_dls_path.png"]  # whole, no .partial


@pytest.mark.parametrize(
    ("hook", "written"),
    [("snac_gym.apps.demo:write_log@1", []), ("snac_gym.apps.demo:write_text_whole@1", ["reach_dls_log.parquet"])],
    ids=["as the log is written", "as the summary is written"],
)
def test_demo_interrupted_while_writing_its_log_says_which_files_it_wrote(tmp_path, hook, written):
    out = tmp_path / "demo"
    args = ["demo", "--task", "reach", "--controller", "dls", "--steps", "50", "--no-plots", "--out", str(out)]
    code, err, _ = _run(args, "SIGHUP", hook=hook)
    assert code == 128 + signal.SIGHUP, err
    kept = (
        f"only {written[0]} of its log and summary was written, whole, in {out}/" if written else "nothing was written"
    )
    assert _one_line(err) == f"interrupted by SIGHUP: the run ended, but {kept}"
    # no partial file either; with nothing written, not the folder the demo made either
    assert (sorted(p.name for p in out.iterdir()) if out.exists() else []) == written and out.exists() == bool(written)


# -- train-ppo: a checkpoint to resume, every evaluation row kept ----------------------------------------
@pytest.mark.rl
@pytest.mark.parametrize(
    "hook",
    ["snac_gym.ppo.train:build_vec_env@1", "snac_gym.ppo.train:_make_callback@1"],
    ids=["after its config is written", "after its logger and state are made"],
)
def test_train_ppo_interrupted_before_its_first_timestep_leaves_no_half_made_run(tmp_path, tiny_ppo, hook):
    """ "nothing was trained; run the command again" is only true if the folder holds no run-in-progress: its config,
    a state saying "running" and the logger's files are removed (and the folder, which the run made)."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "run"
    args = ["train-ppo", "--task", "reach", "--out", str(out), "--config", str(tiny_ppo(tmp_path)), "--no-progress"]
    code, err, _ = _run(args, "SIGTERM", hook=hook)
    assert code == 128 + signal.SIGTERM, err
    assert _one_line(err) == "interrupted by SIGTERM: nothing was trained; run the command again"
    assert not out.exists(), sorted(out.rglob("*"))


@pytest.mark.rl
def test_a_resume_interrupted_before_its_first_timestep_leaves_the_run_as_it_was(tmp_path, tiny_ppo):
    """ "the checkpoint is unchanged": so is the rest of the run's folder, which the resume had begun to rewrite (its
    config, a state saying "running", a new segment's logs)."""
    pytest.importorskip("stable_baselines3")
    from snac_gym.ppo.train import train_ppo

    out = tmp_path / "run"
    train_ppo("reach", out, timesteps=32, config_path=tiny_ppo(tmp_path), log=lambda line: None)
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    args = ["train-ppo", "--task", "reach", "--out", str(out), "--resume", "--timesteps", "96", "--no-progress"]
    code, err, _ = _run(args, "SIGTERM", hook="snac_gym.ppo.train:_make_callback@1")
    assert code == 128 + signal.SIGTERM, err
    assert _one_line(err) == "interrupted by SIGTERM: the checkpoint is unchanged; run the command again"
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert sorted(after) == sorted(before) and after == before


@pytest.mark.rl
@pytest.mark.slow(seconds=8)
@pytest.mark.parametrize("signame", MID_RUN_SIGNALS)
def test_train_ppo_interrupted_mid_training_saves_a_checkpoint_that_resumes(tmp_path, signame, tiny_ppo):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "run"
    hook = "snac_gym.ppo.envs:PPOTrainingWrapper.step@50"  # the 50th env step (of two envs): mid-training
    config = tiny_ppo(tmp_path, timesteps=96, normalize_obs=False)
    args = ["train-ppo", "--task", "reach", "--out", str(out), "--config", str(config), "--no-progress"]
    code, err, _ = _run(args, signame, hook=hook)
    assert code == 128 + int(getattr(signal, signame)), err
    state = json.loads((out / "state.json").read_text())
    assert state["status"] == "interrupted" and state["interrupted_by"] == signame
    assert _one_line(err) == (
        f"interrupted by {signame} during training: checkpoint of {state['timesteps']} timesteps saved in "
        f"{out / 'checkpoint'}/ with every evaluation so far; continue with --resume --out {out}"
    )
    manifest = json.loads((out / "checkpoint" / "sha256.json").read_text())
    assert manifest["timesteps"] == state["timesteps"] and set(manifest["sha256"]) == {
        "model.zip",
        "vecnormalize.pkl",
        "policy.npz",
    }
    assert not (out / "checkpoint.tmp").exists() and not (out / "checkpoint.old").exists()
    if signame == "SIGHUP":  # one resume (the others' checkpoints are the same kind of file)
        from snac_gym.ppo.train import train_ppo

        resumed = train_ppo("reach", out, resume=True, log=lambda line: None)
        assert resumed.status == "finished" and resumed.timesteps >= 96


@pytest.mark.rl
@pytest.mark.slow(seconds=8)
def test_a_resumed_training_keeps_the_evaluation_row_the_interrupt_cut(tmp_path, monkeypatch, tiny_ppo):
    """Interrupted inside its second evaluation, then resumed: the evaluation rows are at the timesteps of an
    uninterrupted run's, and those before the interrupt are the same rows (the resumed segment is not
    bit-identical: SB3 saves neither the random generators nor the rollout in flight, docs/ppo.md)."""
    pytest.importorskip("stable_baselines3")
    import snac_gym.ppo.train as train

    config = tiny_ppo(tmp_path, timesteps=128, normalize_obs=False)
    whole = train.train_ppo("reach", tmp_path / "whole", seed=5, config_path=config, log=lambda line: None)
    assert whole.status == "finished"
    expected, _ = train.read_training_log(tmp_path / "whole")

    original = train.evaluate_policy_file
    calls = [0]

    def interrupted_second(*args, **kwargs):
        calls[0] += 1
        if calls[0] == 2:
            raise KeyboardInterrupt  # as a signal handler raises it, mid-evaluation
        return original(*args, **kwargs)

    monkeypatch.setattr(train, "evaluate_policy_file", interrupted_second)
    cut = train.train_ppo("reach", tmp_path / "cut", seed=5, config_path=config, log=lambda line: None)
    assert cut.status == "interrupted"
    rows, _ = train.read_training_log(tmp_path / "cut")
    assert [r["timesteps"] for r in rows] == [expected[0]["timesteps"]]  # the second row was cut
    monkeypatch.setattr(train, "evaluate_policy_file", original)
    resumed = train.train_ppo("reach", tmp_path / "cut", resume=True, log=lambda line: None)
    assert resumed.status == "finished"
    rows, _ = train.read_training_log(tmp_path / "cut")
    assert [r["timesteps"] for r in rows] == [r["timesteps"] for r in expected]
    for key in ("success_rate", "mean_cost", "mean_final_error_m"):  # the cut evaluation, redone: the same policy
        assert [r[key] for r in rows[:2]] == [r[key] for r in expected[:2]], key
    state = json.loads((tmp_path / "cut" / "state.json").read_text())
    assert state["best"]["timesteps"] in [r["timesteps"] for r in rows]


@pytest.mark.rl
@pytest.mark.parametrize("name", ["model.zip", "vecnormalize.pkl", "policy.npz"])
def test_a_checkpoint_file_with_one_flipped_bit_is_refused_on_resume(tmp_path, name, tiny_ppo):
    pytest.importorskip("stable_baselines3")
    from snac_gym.ppo.train import train_ppo

    out = tmp_path / "run"
    config = tiny_ppo(tmp_path, timesteps=96, normalize_obs=False)
    assert train_ppo("reach", out, timesteps=32, config_path=config, log=lambda line: None).status == "finished"
    path = out / "checkpoint" / name
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=f"checkpoint file {path} does not match the sha256 written with it"):
        train_ppo("reach", out, timesteps=64, resume=True, log=lambda line: None)


SET_NAME = r"""
import os, signal, sys
from snac_gym.apps.cli import app, main

@app.command("probe")
def probe():
    class Field:
        def __set_name__(self, owner, name):  # what a dataclass field runs as its class is made, in an import
            os.kill(os.getpid(), signal.SIGTERM)
            sum(range(200_000))  # the handler runs here

    class Made:
        field = Field()

    print("made", flush=True)

sys.argv = ["snac-gym", "probe"]
main()
"""


def test_a_stop_signal_while_a_class_is_made_is_a_stop_signal_not_a_traceback():
    """Python 3.11 wraps what ``__set_name__`` raises in a RuntimeError: a SIGTERM that lands while an import makes a
    dataclass (pandas' ``IOArgs`` did, in ``snac-gym real``'s first second) came out as a traceback and exit 1."""
    done = subprocess.run([sys.executable, "-c", SET_NAME], capture_output=True, text=True, timeout=60)
    assert done.returncode == 128 + int(signal.SIGTERM), done.stderr
    assert _one_line(done.stderr) == "interrupted by SIGTERM while the command was starting: nothing was written"
    assert "made" not in done.stdout


# -- bench: the tables printed are whole ----------------------------------------------------------------
@pytest.mark.slow(seconds=4)
def test_bench_interrupted_after_a_table_says_the_printed_tables_are_complete(tmp_path):
    hook = "snac_gym.apps.bench:run_substep_study@1"  # after the env table was printed
    code, err, out = _run(["bench", "--steps", "100", "--no-panda", "--substeps"], "SIGQUIT", hook=hook)
    assert code == 128 + int(signal.SIGQUIT), err
    assert _one_line(err) == "interrupted by SIGQUIT: bench writes no files; the tables printed above are complete"
    assert "steps/s" in out
    first = out.splitlines()[0]  # the machine and its load, before any figure
    assert first.startswith("machine: ") and " CPU" in first and f"({llvmlite.binding.get_host_cpu_name()})" in first


def test_the_compiled_kernels_hold_the_same_stop_signals_as_the_commands():
    from snac_gym.common._signals import STOP_SIGNALS
    from snac_gym.kernels import compiled

    assert tuple(compiled._STOP_SIGNALS) == tuple(STOP_SIGNALS)


WEAKREF_CALLBACK = r"""
import gc, os, signal, sys, time, weakref
from snac_gym.common._signals import stop_signals_raise
class Thing:
    pass
def callback():
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(200_000))  # the handler runs here, in a weakref callback, where Python drops what it raises
try:
    with stop_signals_raise():
        thing = Thing()
        weakref.finalize(thing, callback)
        del thing
        gc.collect()
        for _ in range(300):
            time.sleep(0.01)
    print("not interrupted")
except KeyboardInterrupt as exc:
    print("interrupted", exc)
"""


def test_a_signal_handled_inside_a_weakref_callback_is_not_lost():
    """Raised in a weakref or garbage-collector callback, the interrupt is dropped as "unraisable": the run
    went on to its end with exit 0 (seen twice in full test runs on a loaded machine, in a command's first
    second). The guard's unraisable hook sends the signal again, to be raised where it can be."""
    done = subprocess.run([sys.executable, "-c", WEAKREF_CALLBACK], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == "interrupted SIGTERM" and "Exception ignored" not in done.stderr, (
        done.stdout,
        done.stderr,
    )


#: ``evaluate`` with mink, whose import loads mujoco's pybind11 modules, and a stop signal handled while one of
#: them initialises: the finder below runs inside mujoco._specs' init (which imports mujoco._structs).
IN_EXTENSION_INIT = r"""
import importlib.abc, os, signal, sys
sys.argv = ["snac-gym", *sys.argv[1:]]
class SignalInsideAnExtensionsInit(importlib.abc.MetaPathFinder):
    sent = False
    def find_spec(self, name, path, target=None):
        if name == "mujoco._structs" and "mujoco._specs" in sys.modules and not self.sent:
            self.sent = True
            os.kill(os.getpid(), signal.SIGTERM)
            sum(range(200_000))  # the handler runs here, under the extension's init
        return None
sys.meta_path.insert(0, SignalInsideAnExtensionsInit())
from snac_gym.apps.cli import main
main()
"""


def test_a_signal_handled_while_a_c_extension_initialises_is_not_lost(tmp_path):
    """Raised under a pybind11 module's init, the interrupt becomes ``ImportError("initialization failed")``:
    mink then looked like a missing extra and the run went on to its end (seen as a 120 s hang of a test
    in this file on a loaded machine). The handler sends it again, to be raised once the import returned."""
    pytest.importorskip("mink")
    out = tmp_path / "out"
    args = [
        "evaluate",
        "--out",
        str(out),
        "--samples",
        "4",
        "--controllers",
        "mink",
        "--task",
        "reach",
        "--no-progress",
    ]
    done = subprocess.run(
        [sys.executable, "-c", IN_EXTENSION_INIT, *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert done.returncode == 128 + signal.SIGTERM, done.stderr
    assert _one_line(done.stderr).startswith("interrupted by SIGTERM"), done.stderr


def test_an_interrupt_behind_an_import_error_is_raised_as_the_interrupt(monkeypatch):
    from snac_gym.common import extras

    def converted(module):  # what a C extension's init makes of an interrupt
        try:
            raise KeyboardInterrupt("SIGTERM")
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(extras.importlib, "import_module", converted)
    with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
        extras.require("mink", "ik", "mink")
    monkeypatch.setattr(extras.importlib, "import_module", lambda module: (_ for _ in ()).throw(ImportError(module)))
    with pytest.raises(extras.MissingExtraError, match="mink needs the 'ik' extra"):
        extras.require("mink", "ik", "mink")


def test_a_signal_that_comes_while_the_unraisable_hook_runs_is_sent_again_not_raised_there(monkeypatch):
    """The hook's own resend may land before the hook has returned (Python 3.13 under load): raised there, it
    would be dropped as "Exception ignored in sys.unraisablehook"."""
    from snac_gym.common import _signals

    sent: list[int] = []
    monkeypatch.setattr(_signals, "send_again", sent.append)
    guard = _signals.SignalGuard()
    handlers, previous = guard.install((signal.SIGTERM,))
    try:

        class Unraisable:
            exc_value = _signals.TerminationSignal(signal.SIGTERM)

        def landing_inside(unraisable, hook):  # the signal arrives while the hook is still running
            guard.handle(signal.SIGTERM, None)
            sent.append(-1)

        monkeypatch.setattr(guard, "unraisable", landing_inside)
        sys.unraisablehook(Unraisable())
        assert sent == [signal.SIGTERM, -1] and guard.received == []  # sent again, nothing raised
        with pytest.raises(_signals.TerminationSignal):
            guard.handle(signal.SIGTERM, None)  # outside the hook it raises as before
    finally:
        sys.unraisablehook = previous
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
