"""The evaluator and the CLI under misuse: bad inputs give one-line errors, resumes never mix runs, workers
never outlive the run. Each test names the input it tries (docs/robustness.md lists them)."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.effort import matching as effort_matching
from snac_gym.evaluation.execution.executors import ProcessExecutor, check_ray_reachable, max_workers
from snac_gym.evaluation.store import RESULTS_FILE, RunDirectoryError, RunStore
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.ppo.policy import shipped_model_path
from snac_gym.ppo.policy_file import PolicyFile, PolicyFileError

SMALL = {"samples": 2, "effort_samples": 0, "horizons": {"reach": 0.2, "track": 0.2}, "chunk_size": 1,
         "progress": False, "plots": False}  # fmt: skip
HEADER = "task,q0_0,q0_1,q0_2,q0_3,q0_4,q0_5,target_0,target_1,target_2"
PAPER_ROW = "reach,-0.51,-1.04,1.48,-1.82,-1.45,-1.62,-0.658,0.626,0.407"


def _config(out: Path, **changes) -> EvaluationConfig:
    return EvaluationConfig(out=out, **{**SMALL, **changes})


def _cli(*arguments: str):
    return CliRunner().invoke(app, list(arguments))


def _one_line_error(result, message: str) -> None:
    """Exit code 2, the message, one line, no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert message in lines[0], result.output


# -- --resume never mixes runs -------------------------------------------------------------------


def _modified_model(source: Path, target: Path) -> None:
    """A valid reach policy file whose actor differs from ``source``'s (a retrained model)."""
    model = PolicyFile.load(source)
    weight, bias = model.action_layer
    changed = dataclasses.replace(model, action_layer=(weight * 0.5, bias))
    changed.save(target)


def test_resume_refuses_a_changed_model_file_or_controller_parameter(tmp_path):
    model = tmp_path / "model.npz"
    shutil.copyfile(shipped_model_path("reach"), model)
    config = _config(
        tmp_path / "run",
        tasks=("reach",),
        controllers=("ppo",),
        match_effort=False,
        controller_kwargs={"ppo": {"model_path": str(model)}},
    )
    first = run_evaluation(config)
    resumed = run_evaluation(dataclasses.replace(config, resume=True))
    pd.testing.assert_frame_equal(first, resumed, check_exact=True)  # unchanged inputs: resumes

    _modified_model(shipped_model_path("reach"), model)  # the model is replaced between the runs
    with pytest.raises(RunDirectoryError, match="inputs differ.*controller_inputs.*model.npz"):
        run_evaluation(dataclasses.replace(config, resume=True))
    with pytest.raises(RunDirectoryError, match="inputs differ.*controller_kwargs"):
        run_evaluation(dataclasses.replace(config, resume=True, controller_kwargs={"ppo": {"action_scale": 2.0}}))


def test_resume_refuses_a_changed_samples_file(tmp_path):
    samples = tmp_path / "samples.csv"
    samples.write_text(f"{HEADER}\n{PAPER_ROW}\n")
    config = _config(tmp_path / "run", tasks=("reach",), controllers=("dls",), match_effort=False, samples_file=samples)
    run_evaluation(config)
    samples.write_text(f"{HEADER}\n{PAPER_ROW}\n{PAPER_ROW.replace('0.407', '0.41')}\n")
    with pytest.raises(RunDirectoryError, match="samples_file_sha1"):
        run_evaluation(dataclasses.replace(config, resume=True))


def test_resume_refuses_part_files_that_do_not_belong_to_the_run(tmp_path):
    common = {"tasks": ("reach",), "controllers": ("dls",), "match_effort": False}
    other = _config(tmp_path / "other", seed=1, **common)
    run_evaluation(other)
    config = _config(tmp_path / "run", **common)
    reference = run_evaluation(config)
    parts = sorted((config.out / "parts").glob("*.parquet"))
    assert len(parts) == 2

    shutil.copyfile(other.out / "parts" / parts[0].name, parts[0])  # same name, another run's samples
    with pytest.raises(RunDirectoryError, match=f"{parts[0].name} belongs to another run"):
        run_evaluation(dataclasses.replace(config, resume=True))

    shutil.copyfile(parts[1], parts[0])  # this run's part under another chunk's name: duplicate samples
    with pytest.raises(RunDirectoryError, match=f"{parts[0].name} belongs to other samples"):
        run_evaluation(dataclasses.replace(config, resume=True))

    parts[0].unlink()  # removed as the message says: recomputed, nothing duplicated
    resumed = run_evaluation(dataclasses.replace(config, resume=True))
    pd.testing.assert_frame_equal(resumed, reference, check_exact=True)
    assert not resumed.duplicated(["task", "controller", "sample"]).any()


def test_a_folder_in_use_by_a_run_is_refused_until_it_ends(tmp_path):
    manifest = {"options": 1}
    with RunStore(tmp_path, manifest, resume=False) as first:
        first.begin()
        with pytest.raises(RunDirectoryError, match=f"in use by another run \\(pid {os.getpid()}\\)"):
            RunStore(tmp_path, manifest, resume=True)
    with RunStore(tmp_path, manifest, resume=True):  # the lock went with the first run
        pass


def test_the_same_command_again_says_whether_the_run_there_is_finished_unfinished_or_another(tmp_path):
    """Running a command again into its --out is the usual second step (to see it cached, or after a stop): the
    refusal says which case it met, and suggests --resume only where --resume would be taken."""
    manifest = {"seed": 0, "controllers": ["dls"]}
    with RunStore(tmp_path, manifest, resume=False) as store:
        store.begin()
    with pytest.raises(RunDirectoryError, match="already holds this run, unfinished; pass --resume to continue it"):
        RunStore(tmp_path, manifest, resume=False)
    with pytest.raises(
        RunDirectoryError, match=r"holds another run \(its inputs differ: controllers, seed\); choose another"
    ):
        RunStore(tmp_path, {"seed": 1, "controllers": ["lqr"]}, resume=False)
    (tmp_path / RESULTS_FILE).write_bytes(b"")
    with pytest.raises(RunDirectoryError, match="holds this run, finished; pass --resume to write its reports again"):
        RunStore(tmp_path, manifest, resume=False)
    with RunStore(tmp_path, manifest, resume=True):  # as it says
        pass


def test_a_run_that_ends_before_its_sample_set_leaves_no_lock_nor_a_folder_it_made(tmp_path, monkeypatch):
    """The folder lock is a file: a run refused, failed or interrupted before run.json (nothing written) removes it,
    and the folder too if it made it, so that "nothing was written" holds; a begun run's folder keeps its lock."""
    import snac_gym.evaluation.runner as runner

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "generate_samples", interrupted)
    config = EvaluationConfig(out=tmp_path / "new", samples=2, match_effort=False, progress=False, plots=False)
    with pytest.raises(KeyboardInterrupt):
        run_evaluation(config)
    assert not config.out.exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    with pytest.raises(KeyboardInterrupt):
        run_evaluation(dataclasses.replace(config, out=mine))
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    with pytest.raises(RunDirectoryError, match="holds no run to resume"):
        RunStore(tmp_path / "refused", {"options": 1}, resume=True)
    assert not (tmp_path / "refused").exists()
    with RunStore(tmp_path / "begun", {"options": 1}, resume=False) as store:
        store.begin()
    assert sorted(p.name for p in (tmp_path / "begun").iterdir()) == [".lock", "parts", "run.json"]


def test_a_calibration_record_of_another_run_is_refused(tmp_path):
    with RunStore(tmp_path / "other", {"seed": 1}, resume=False) as other:
        other.save_calibration("reach/dls/search1", {"value": 2.0})
    with RunStore(tmp_path / "run", {"seed": 0}, resume=False) as store:
        store.begin()
    shutil.copyfile(tmp_path / "other" / "calibration.json", tmp_path / "run" / "calibration.json")
    with pytest.raises(RunDirectoryError, match="calibration.json does not belong to the run"):
        RunStore(tmp_path / "run", {"seed": 0}, resume=True)


def test_missing_samples_file_and_corrupt_run_json_are_one_line_errors(tmp_path):
    _one_line_error(
        _cli("evaluate", "--out", str(tmp_path / "a"), "--samples-file", str(tmp_path / "nope.csv")),
        "nope.csv: no such samples file",
    )
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "run.json").write_text("{not json")
    _one_line_error(
        _cli("evaluate", "--out", str(tmp_path / "b"), "--resume", "--controllers", "dls", "--samples", "2"),
        "run.json is unreadable (JSONDecodeError",
    )


# -- one-line errors -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--out", ""], "--out must name a folder"),
        (["--out", "  "], "--out must name a folder"),
        (["--horizon", "inf"], "the horizon must be a positive finite number of seconds"),
        (["--horizon", "nan"], "the horizon must be a positive finite number of seconds"),
        (["--horizon", "1e7"], "the reach horizon must be between one control period (0.008 s) and 1000 s"),
        (["--param", "dsl.gain=50"], "--param dsl.gain: no controller is registered as 'dsl'; did you mean 'dls'?"),
        (["--controllers", "svf", "--param", "dls.gain=2"], "'dls' is not among the evaluated controllers (svf)"),
        (["--param", "ppo.model_path=/nonexistent.npz"], "controller 'ppo' cannot be built"),
        (["--param", "snac.gamma=0.9"], "--param snac.gamma: 'snac' has no argument 'gamma'; its arguments: Q, R, lea"),
        (["--param", "lqr.q=2"], "--param lqr.q: 'lqr' has no argument 'q'; did you mean 'Q'?"),
        (["--effort-target", "inf"], "--effort-target must be a positive finite number, got inf"),
        (["--effort-target", "5", "--effort-statistic", "max"], "the max statistic is at most 3.2"),
        (["--effort-target", "1.5", "--effort-statistic", "median-peak"], "statistic is at most 1"),
        (["--workers", "100000"], "workers must be between 1 and "),  # the bound: test_workers_are_bounded_by_the_cpus
        (["--ray", "ray://"], "use 'local', 'auto', HOST:PORT"),
        (["--ray", ""], "--ray must be 'local' or a Ray cluster's address"),  # not read as "no Ray"
    ],
)
def test_bad_evaluate_options_are_one_line_errors(tmp_path, arguments, message):
    base = ["evaluate", "--samples", "2", "--no-progress"]
    if "--out" not in arguments:
        base += ["--out", str(tmp_path / "out")]
    _one_line_error(_cli(*base, *arguments), message)
    assert not (tmp_path / "out" / "run.json").exists()


@pytest.mark.parametrize(
    ("arguments", "option"),
    [
        (["demo", "--out", ""], "--out"),
        (["demo", "--out", " "], "--out"),
        (["real", "--connection", "sim", "--out", ""], "--out"),
        (["plot", ""], "'LOG'"),
        (["plot", "demo_out", "--out", ""], "--out"),
        (["train-ppo", "--task", "reach", "--out", ""], "--out"),
        (["train-ppo", "--task", "reach", "--out", "run", "--config", ""], "--config"),
        (["train-ppo", "--task", "reach", "--out", "run", "--init-from", ""], "--init-from"),
        (["evaluate", "--samples-file", ""], "--samples-file"),
        (["evaluate", "--export-samples", ""], "--export-samples"),
    ],
)
def test_an_empty_path_is_refused_naming_its_option_not_taken_for_the_current_folder(
    tmp_path, monkeypatch, arguments, option
):
    """``Path("")`` is ``.``: an unset shell variable (``--out "$OUT"``) would write into the current folder."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo_out").mkdir()  # plot's LOG, so that only the --out given is wrong
    result = _cli(*arguments)
    assert result.exit_code == 2, result.output
    assert f"Invalid value for {option}: must name " in result.output
    assert "got an empty string" in result.output
    assert sorted(path.name for path in tmp_path.iterdir()) == ["demo_out"]
    assert not any((tmp_path / "demo_out").iterdir())


def _options_taking_a_value() -> list[tuple[str, str]]:
    import typer

    command = typer.main.get_command(app)
    return [
        (name, max(param.opts, key=len))
        for name, sub in command.commands.items()
        for param in sub.params
        if type(param).__name__ == "TyperOption" and not param.is_flag and param.name != "help"
    ]


#: What a command needs besides the option tried, so that the option is the only thing wrong.
_NEEDS = {"plot": ["demo_out"], "train-ppo": ["--task", "reach", "--out", "run"], "real": ["--connection", "sim"]}
#: Deprecated names: their refusal names the option that replaced them.
_RENAMED = {"--backend": ("--engine", "--connection")}


@pytest.mark.parametrize(("command", "option"), _options_taking_a_value())
def test_every_option_of_every_command_refuses_an_empty_value_naming_it(tmp_path, monkeypatch, command, option):
    """Generated from the commands themselves, so that an option added later is tried too: an empty value (an unset
    shell variable) is never taken for a default, the current folder or "none", and nothing is written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo_out").mkdir()
    # A deprecated name still says so before its value is refused.
    warned = (
        pytest.warns(DeprecationWarning, match=f"{option} is deprecated")
        if option in _RENAMED
        else contextlib.nullcontext()
    )
    with warned:
        result = _cli(command, *_NEEDS.get(command, []), option, "")
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert any(name in result.output for name in (option, *_RENAMED.get(option, ()))), result.output
    assert sorted(path.name for path in tmp_path.iterdir()) == ["demo_out"]


def test_demo_refuses_an_unknown_robot_naming_the_option_before_its_imports(tmp_path):
    result = _cli("demo", "--robot", "", "--out", str(tmp_path / "out"))
    assert result.exit_code == 2, result.output
    assert "Invalid value for --robot: unknown robot ''; choose one of [" in result.output
    assert not (tmp_path / "out").exists()


def test_an_out_that_is_a_file_or_not_writable_is_a_one_line_error(tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("")
    _one_line_error(_cli("evaluate", "--out", str(a_file), "--samples", "2"), "is a file, not a folder")
    if os.geteuid() == 0:  # root writes anywhere a mode allows: use a folder no one can create in
        read_only = Path("/sys/snac_gym_test_out")
        message = "cannot create the output folder /sys/snac_gym_test_out"
    else:
        read_only = tmp_path / "read_only"
        read_only.mkdir(mode=0o500)
        message = "is not writable"
    _one_line_error(
        _cli("evaluate", "--out", str(read_only), "--samples", "2", "--controllers", "dls", "--no-match-effort"),
        message,
    )


def test_demo_duration_beyond_the_bound_is_a_one_line_error(tmp_path):
    for duration in ("1e9", "inf"):
        _one_line_error(
            _cli("demo", "--duration", duration, "--out", str(tmp_path), "--no-plots"),
            "the demo duration must be in (0, 1000] s",
        )


def _samples_file(tmp_path: Path, text: str | bytes) -> Path:
    path = tmp_path / "samples.csv"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (
            f"task,sample,{HEADER[5:]}\nreach,{2**64},{PAPER_ROW[6:]}\n",
            f"row 1 (line 2), column 'sample': {2**64} is outside [0, 9223372036854775807]",
        ),
        (
            f"{HEADER}\n{PAPER_ROW.replace('0.407', '1' * 200_000)}\n",
            "line 2: not readable as CSV (field larger than field limit",
        ),
        (f"{HEADER}\n{PAPER_ROW.replace('0.407', '1' * 2000)}\n", "column 'target_2': a cell of 2000 characters"),
        (f"{HEADER}\n{PAPER_ROW}\xff\n".encode("latin-1"), "not UTF-8 text (byte 0xff at offset"),
        (f"{HEADER}\n\n\n\n{PAPER_ROW}\n\n\n\n{PAPER_ROW.replace('0.626', 'oops')}\n", "row 2 (line 9)"),
        (
            (
                f"task,{HEADER[5:].replace('target_0,target_1,target_2', 'centre_0,centre_1,centre_2')},"
                "semi_axis_0,semi_axis_1,angular_speed\n"
                f"track,{PAPER_ROW[6:].replace('-0.658,0.626,0.407', '-0.7,0,0.5')},0.2,0.2,0\n"
            ),
            "angular_speed must be at least 0.001 rad/s",
        ),
    ],
    ids=["id-beyond-int64", "cell-beyond-csv-limit", "oversized-cell", "non-utf8", "blank-lines", "omega-zero"],
)
def test_bad_samples_files_are_one_line_errors_naming_the_file(tmp_path, content, message):
    path = _samples_file(tmp_path, content)
    out = tmp_path / "out"
    arguments = ("evaluate", "--out", str(out), "--samples-file", str(path), "--controllers", "dls", "--no-progress")
    result = _cli(*arguments)
    _one_line_error(result, message)
    assert str(path) in result.output
    assert not (out / "run.json").exists()  # refused before the run began: fixing the file is enough
    path.write_text(f"{HEADER}\n{PAPER_ROW}\n")
    fixed = _cli(*arguments, "--task", "reach", "--no-match-effort", "--horizon", "0.1")
    assert fixed.exit_code == 0, fixed.output


def test_an_unmatched_effort_is_reported_on_stderr(tmp_path, monkeypatch):
    real = effort_matching.within
    monkeypatch.setattr(effort_matching, "within", lambda effort, target, tolerance: False)
    result = CliRunner().invoke(
        app,
        [
            "evaluate",
            "--out",
            str(tmp_path),
            "--task",
            "reach",
            "--samples",
            "2",
            "--controllers",
            "dls,svf",
            "--effort-reference",
            "dls",
            "--effort-samples",
            "0",
            "--horizon",
            "0.2",
            "--no-progress",
        ],
    )
    monkeypatch.setattr(effort_matching, "within", real)
    assert result.exit_code == 0, result.output
    assert "warning: effort not matched for svf (reach)" in result.output


# -- --ray -----------------------------------------------------------------------------------------


def test_an_unreachable_ray_address_fails_within_the_stated_timeout():
    import socket

    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(RuntimeError, match=f"cannot reach the Ray cluster at 127.0.0.1:{port} within 2 s"):
        check_ray_reachable(f"127.0.0.1:{port}", timeout=2.0)
    check_ray_reachable("auto")  # found by Ray itself on this machine: nothing to probe


# -- process hygiene -------------------------------------------------------------------------------


def _direct_children(pid: int) -> set[int]:
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            pass
    return found


def _children(pid: int) -> set[int]:
    """The run's worker processes: the fork server's children (the run's grandchildren), or the
    run's own forked children when there is no fork server."""
    direct = _direct_children(pid)
    grandchildren = set().union(*(_direct_children(child) for child in direct)) if direct else set()
    return grandchildren or {
        c for c in direct if "forkserver" not in _command(c) and "resource_tracker" not in _command(c)
    }


def _alive(pid: int) -> bool:
    return _proc_field(pid, "stat") not in ("Z", "X", "?")  # "?": gone


def _wait_for(condition, timeout: float = 120.0) -> bool:
    """Poll ``condition`` until it holds; ``False`` only if it never does (a hang guard, not a timing check)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def _interrupted_line(signal_name: str, out: Path) -> str:
    """The CLI's one line: a run is recorded (and can be resumed) once its samples are drawn."""
    if (out / "run.json").exists():
        return f"interrupted by {signal_name}: finished jobs are kept in {out}/; continue with --resume"
    return f"interrupted by {signal_name} while drawing the samples: nothing to resume; run the command again"


def _start_long_run(tmp_path: Path) -> subprocess.Popen:
    """A two-worker evaluation far longer than the test, in its own process group, with Python's fault handler on
    in it and its workers (:func:`_communicate`)."""
    command = [
        sys.executable,
        "-X",
        "faulthandler",
        "-m",
        "snac_gym.apps.cli",
        "evaluate",
        "--out",
        str(tmp_path / "run"),
        "--workers",
        "2",
        "--controllers",
        "dls,svf",
        "--effort-reference",
        "dls",
        "--samples",
        "2000",
        "--task",
        "reach",
        "--horizon",
        "30",
        "--no-progress",
    ]
    return subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, cwd=tmp_path
    )


def _descendants(pid: int) -> list[int]:
    found, pending = [], [pid]
    while pending:
        children = sorted(_direct_children(pending.pop()))
        found += children
        pending += children
    return found


def _communicate(process: subprocess.Popen, timeout: float = 120.0) -> tuple[bytes, bytes]:
    """``process.communicate(timeout)``; past the timeout, a failure that says what still held the run's pipes.

    Every process of the run (the evaluator, its fork server and workers) still alive is listed with its state and
    kernel wait channel and sent SIGABRT: with the fault handler on (:func:`_start_long_run`) each prints every
    thread's Python stack to the run's stderr, which the failure shows. A hang seen once in CI left no trace.
    """
    try:
        return process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        alive = [pid for pid in [process.pid, *_descendants(process.pid)] if _alive(pid)]
        lines = [
            f"{pid} {_proc_field(pid, 'stat')} wchan={_proc_field(pid, 'wchan')} {_command(pid)[:160]}" for pid in alive
        ]
        for pid in reversed(alive):  # the workers first, then their fork server, the evaluator last
            if _command(pid).startswith(sys.executable):  # still one of the run's (a pid may have been reused)
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGABRT)
        try:
            _, err = process.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            _, err = process.communicate()
        pytest.fail(
            f"the run's pipes were still open {timeout:.0f} s after the signal; alive then:\n" + "\n".join(lines)
            + "\nstderr, with the stacks dumped on SIGABRT:\n" + err.decode(errors="replace")[-20000:]
        )  # fmt: skip


def _command(pid: int) -> str:
    """The process's command line, its arguments joined by spaces ("?" if it is gone)."""
    return _proc_field(pid, "cmdline").replace("\0", " ").strip()


def _proc_field(pid: int, name: str) -> str:
    """``/proc/PID/NAME``: the process's state letter for ``stat``, the file's text otherwise (``cmdline``: its
    arguments, each ended by NUL); "?" if it is gone."""
    try:
        text = Path(f"/proc/{pid}/{name}").read_text()
    except OSError:
        return "?"
    return text.rsplit(")", 1)[1].split()[0] if name == "stat" else text.strip()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM])
def test_workers_die_with_their_parent_and_release_its_pipes(tmp_path, signum):
    process = _start_long_run(tmp_path)
    try:
        assert _wait_for(lambda: len(_children(process.pid)) >= 2), process.stderr.read().decode()
        workers = _children(process.pid)
        process.send_signal(signum)
        # A reader of the run's pipes gets end-of-file: no worker holds them open any more.
        _, err = _communicate(process)
        assert _wait_for(lambda: not any(_alive(w) for w in workers))
    finally:
        if process.poll() is None:
            process.kill()
    if signum == signal.SIGTERM:  # handled like Ctrl-C: one line, the run kept for --resume
        assert process.returncode == 128 + signal.SIGTERM
        assert err.decode().strip().splitlines() == [_interrupted_line("SIGTERM", tmp_path / "run")]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_prints_one_line_and_no_worker_traceback(tmp_path):
    process = _start_long_run(tmp_path)
    try:
        assert _wait_for(lambda: len(_children(process.pid)) >= 2), process.stderr.read().decode()
        workers = _children(process.pid)
        os.killpg(process.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole foreground group
        _, err = _communicate(process)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130
    assert err.decode().strip().splitlines() == [_interrupted_line("SIGINT", tmp_path / "run")]
    assert _wait_for(lambda: not any(_alive(w) for w in workers))


def test_workers_are_bounded_by_the_cpus(tmp_path):
    with pytest.raises(ValueError, match=f"workers must be between 1 and {max_workers()} \\(2 per available CPU\\)"):
        run_evaluation(_config(tmp_path, workers=max_workers() + 1))
    assert max_workers() >= 2


def test_process_executor_terminate_ends_running_jobs():
    executor = ProcessExecutor(2)
    processes = list(executor._pool._processes.values())
    assert len(processes) == 2 and all(p.is_alive() for p in processes)  # started eagerly, by this thread
    executor.terminate()
    executor.close()
    assert not any(p.is_alive() for p in processes)


# -- references, weights, rendering, PPO card --------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ({"angular_speed": 0.0}, "angular_speed must be at least 0.001 rad/s in magnitude"),
        ({"angular_speed": 1e6}, "at most 3 m/s can be followed"),
        ({"semi_axes": [1e-300, 0.1]}, "semi_axes must be positive, at least 0.001 m"),
        ({"angular_speed": float("nan")}, "angular_speed must be finite"),
    ],
)
def test_physically_meaningless_ellipses_are_refused_with_their_bound(spec, message):
    from snac_gym.references import Ellipse

    with pytest.raises(ValueError, match=message.replace("(", "\\(")):
        Ellipse.from_dict({"centre": [-0.7, 0.0, 0.5], "semi_axes": [0.2, 0.2], **spec})
    Ellipse.from_dict({"centre": [-0.7, 0.0, 0.5], "semi_axes": [0.2, 0.2], "angular_speed": -0.3})  # valid


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"Q": [-1.0, 1.0, 1.0]}, "Q must be positive definite or semidefinite"),
        ({"Q": [np.nan, 1.0, 1.0]}, "Q must be finite"),
        ({"R": -np.eye(6)}, "R must be positive definite or semidefinite"),
        ({"R": [1.0, 1.0, np.nan, 1.0, 1.0, 1.0]}, "R must be finite"),
        ({"dt": float("inf")}, r"dt \(s\) must be a finite number in \[1e-06, 1\], got inf"),
        (
            {"render_mode": "rgb_array", "render_width": -1},
            "render_width must be a whole number of pixels in \\[1, 8192\\]",
        ),
        ({"render_mode": "rgb_array", "render_height": 0}, "render_height must be a whole number of pixels"),
    ],
)
def test_meaningless_env_arguments_are_refused_in_the_constructor(kwargs, message):
    import gymnasium as gym

    with pytest.raises(ValueError, match=message):
        gym.make("snac_gym/UR10Reach-v0", **kwargs)


def test_trajectory_cost_refuses_infinite_dt_and_negative_weights():
    from snac_gym.control.cost import trajectory_cost

    errors, commands = np.ones((3, 3)), np.ones((3, 6))
    with pytest.raises(ValueError, match=r"dt must be a finite number in \(0, inf\], got inf"):
        trajectory_cost(errors, commands, float("inf"))
    with pytest.raises(ValueError, match="Q must be positive definite or semidefinite"):
        trajectory_cost(errors, commands, 0.008, Q=[1.0, -1.0, 1.0])


def test_a_ppo_model_card_that_describes_another_file_is_refused(tmp_path):
    import gymnasium as gym

    from snac_gym import make_policy

    shipped = shipped_model_path("reach")
    model = tmp_path / "reach.npz"
    shutil.copyfile(shipped, model)
    shutil.copyfile(shipped.with_suffix(".json"), tmp_path / "reach.json")
    env = gym.make("snac_gym/UR10Reach-v0")
    try:
        make_policy("ppo", env, model_path=model)  # the shipped card matches the shipped file
        _modified_model(shipped, model)
        with pytest.raises(PolicyFileError, match="model card .*reach.json does not describe reach.npz: bytes"):
            make_policy("ppo", env, model_path=model)
        (tmp_path / "reach.json").unlink()  # no card: nothing to contradict
        make_policy("ppo", env, model_path=model)
    finally:
        env.close()
