"""The first hour, cold: the README's main command and a small question as a newcomer first runs them, on this machine,
beside their floors and goals; on request `snac-gym bench`'s ratio to panda-gym, the README's two test runs and
`snac-gym real`'s rehearsals on a busy host too.

    python docs/scripts/first_hour.py --out runs/first-hour                   # cold, warm, floor, a cold 50-sample run
    python docs/scripts/first_hour.py --out runs/first-hour --bench --tests   # and the bench and the test suites
    python docs/scripts/first_hour.py --out runs/rehearsal --no-main --rehearsal  # the rehearsals alone
    python docs/scripts/first_hour.py --out runs/clone --no-main --fresh-clone --tests  # the README's blocks, verbatim

``--rehearsal`` runs ``snac-gym real --connection sim`` and ``snac-gym real --dry-run`` (against the emulated UR
controller, started here on the standard ports) beside two ``yes`` processes that keep both cores busy: each must
finish, exit 0 and report its late periods.

Every command runs as a user runs it: the installed ``snac-gym`` console script beside this Python (the test runs: this
Python's ``-m pytest`` with the README's arguments), in a subprocess, in the repository's root, its output unmuted into
``OUT/NAME.log``. The cold runs get ``SNAC_GYM_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` at new, empty folders (the
reference's, the calibration's and numba's caches); the warm run reuses the cold run's, right after it. Each figure
is the command's own clock (its ``wall time`` line) where it prints one, else the wall time measured here, with its
CPU (user + system, the process and the descendants it waited for) and its largest process's peak memory.

``--fresh-clone`` runs the README's main command, and with ``--tests`` its test command, exactly as written (each
block in ``bash``, the install included) in a new clone of this repository's HEAD (what is committed: uncommitted
changes are not in it), with every cache at a new folder: a newcomer's first hour whole. Its figures are the command's
own clock (or pytest's test time) and its wall time with the install.

The floor is ``table1_floor.py``'s (the work the cold and the warm run cannot skip, at this machine's rate in this
hour). What is printed at the end, and written to ``OUT/first_hour.json`` with the machine (its CPU, the one numba
compiles for, its cores and load at each command's start), is one table: each figure, its floor where it has one,
the goal and whether it was met. Nothing else should run meanwhile: every figure here is the machine's CPU time.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
CONTROLLERS = "snac,snac-hjb,lqr,rnn,svf,dls,ppo,optimal"
#: The README's main command's evaluate (its --out aside).
MAIN = ["evaluate", "--workers", "2", "--controllers", CONTROLLERS]
#: The small question: the same controllers and workers on 50 samples.
SMALL = [MAIN[0], "--samples", "50", *MAIN[1:]]
#: The goals of "the first hour, cold": seconds (cold, warm, the small question's wall, the tests' test time), the
#: bench's ratio to panda-gym, the tests' peak memory in GB.
GOALS = {"cold": 60.0, "warm": 30.0, "small": 20.0, "bench": 3.0, "tests": 150.0, "tests_peak_gb": 1.5}
#: Summary columns that are times of the run itself, not results: they differ between any two runs.
TIMED_COLUMNS = re.compile(r"_solve_time_")
#: The kept Table I every run's summary is compared with.
KEPT_TABLE = ROOT / "docs" / "data" / "table1" / "summary.csv"


@dataclass
class Run:
    """One command as it ran: its wall time here, its own clock (``None`` where it prints none), CPU seconds, the
    largest process's peak resident memory (GB), exit code, and the machine's load average when it started."""

    name: str
    command: list[str]
    wall: float
    own_clock: float | None
    cpu: float
    peak_gb: float
    returncode: int
    load: float
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        return self.own_clock if self.own_clock is not None else self.wall


def own_clock(output: str) -> float | None:
    """The seconds of ``snac-gym evaluate``'s last ``wall time 12.3 s; ...`` line, or ``None``."""
    found = re.findall(r"^wall time ([0-9.]+) s\b", output, flags=re.M)
    return float(found[-1]) if found else None


#: pytest's summary line, ``==== 12 passed, 1 skipped in 34.56s (0:00:34) ====``: its seconds.
_PYTEST_SUMMARY = re.compile(r"^=+ .*\b(?:passed|failed|error|errors)\b.* in ([0-9.]+)s\b", flags=re.M)


def pytest_runs_seconds(output: str) -> list[float]:
    """The seconds of every pytest summary line in ``output``, in order: a command that runs pytest twice (the
    README's test command) prints two."""
    return [float(seconds) for seconds in _PYTEST_SUMMARY.findall(output)]


#: ``snac_gym/UR10Reach-v0 (pybullet): 2.67x panda-gym's real-time factor (best runs; round by round 2.44-2.69x,
#: median 2.62x)``, as `snac-gym bench` prints it.
_BENCH_RATIO = re.compile(
    r"^(?P<env>\S+) \((?P<engine>\w+)\): (?P<best>[0-9.]+)x panda-gym's real-time factor"
    r"(?: \(best runs; round by round (?P<low>[0-9.]+)-(?P<high>[0-9.]+)x, median (?P<median>[0-9.]+)x\))?",
    flags=re.M,
)


def bench_ratios(output: str) -> dict[str, dict[str, float]]:
    """Each env's ratio to panda-gym's real-time factor in `snac-gym bench`'s output, by ``env (engine)``: ``best``
    (of the best runs) and, where printed, the round-by-round ``low``, ``high`` and ``median``."""
    ratios = {}
    for match in _BENCH_RATIO.finditer(output):
        figures = {
            key: float(value) for key, value in match.groupdict().items() if key not in ("env", "engine") and value
        }
        ratios[f"{match['env']} ({match['engine']})"] = figures
    return ratios


def readme_command(readme: str, marker: str) -> str:
    """The README's command between its ``<!-- marker -->`` and ``<!-- /marker -->`` lines (as .ci/run reads it)."""
    block = re.search(rf"<!-- {marker} -->\n```\n(.*?)\n```\n<!-- /{marker} -->", readme, flags=re.S)
    if block is None:
        raise ValueError(f"README.md has no command between <!-- {marker} --> markers")
    return block[1]


def readme_pytest_commands(readme: str) -> list[list[str]]:
    """The pytest runs of the README's test command, as argument lists after ``python``: the test time the goal
    counts is theirs, not the install's or the linters'."""
    runs = [shlex.split(step) for step in readme_command(readme, "test-command").split("&&") if " -m pytest" in step]
    if not runs:
        raise ValueError("the README's test command runs no pytest")
    return [words[1:] for words in runs]  # without the venv's python: this script's runs them


def changed_cells(run: Path, kept: Path) -> tuple[int, int]:
    """How many float cells of ``run``'s ``summary.csv`` differ from ``kept``'s (the run's own times left out), and
    how many were compared; NaN equals NaN."""
    import numpy as np
    import pandas as pd

    ours, theirs = pd.read_csv(run / "summary.csv"), pd.read_csv(kept)
    if list(ours["controller"]) != list(theirs["controller"]):
        raise ValueError(f"{run}/summary.csv and {kept} hold different controllers")
    columns = [c for c in ours.columns if ours[c].dtype.kind == "f" and not TIMED_COLUMNS.search(c) and c in theirs]
    a, b = ours[columns].to_numpy(float), theirs[columns].to_numpy(float)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    return int((~same).sum()), int(same.size)


def run(
    name: str, command: list[str], out: Path, env: dict[str, str] | None = None, check: bool = True, cwd: Path = ROOT
) -> Run:
    """``command`` run in ``cwd`` (the repository's root), its output (stdout and stderr together) into
    ``out/name.log``; with ``check``, a failure ends the measurement."""
    log = out / f"{name}.log"
    load = os.getloadavg()[0]
    print(f"{time.strftime('%H:%M:%S')} {name}: {shlex.join(command)} (load {load:.2f})", flush=True)
    with log.open("w", encoding="utf-8") as sink:
        started = time.perf_counter()
        process = subprocess.Popen(command, cwd=cwd, env=env, stdout=sink, stderr=subprocess.STDOUT)
        # wait4: this command's CPU and peak memory (Linux: its largest process's, its waited-for descendants' too)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    output = log.read_text(encoding="utf-8", errors="replace")
    words = shlex.split(command[-1]) if command[:2] == ["bash", "-c"] else command  # a README block: its words
    if "pytest" in words:  # the test time: pytest's own, summed over the runs of a command that runs it twice
        pytest_runs = pytest_runs_seconds(output)
        clock: float | None = sum(pytest_runs) or None
    else:
        pytest_runs, clock = [], own_clock(output) if "evaluate" in words else None
    result = Run(name, command, wall, clock, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 2**20,
                 process.returncode, load)  # fmt: skip
    if len(pytest_runs) > 1:
        result.notes["pytest_runs"] = pytest_runs
    print(f"  exit {result.returncode}, {result.seconds:.1f} s, {result.wall:.1f} s wall, {result.cpu:.1f} CPU s")
    if check and result.returncode != 0:
        raise SystemExit(f"{name} failed (exit {result.returncode}): see {log}")
    return result


def cold_caches() -> dict[str, str]:
    """The environment with the reference's, the calibration's and numba's caches at new, empty folders (removed at
    exit: their compiles and solves serve no later run)."""
    folder = Path(tempfile.mkdtemp(prefix="first-hour-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return {**os.environ, "SNAC_GYM_CACHE_DIR": str(folder / "cache"), "NUMBA_CACHE_DIR": str(folder / "numba")}


Row = tuple[str, str, str, str]


def _goal(value: float, bound: float, at_least: bool = False) -> str:
    met = value >= bound if at_least else value <= bound
    return f"{'≥' if at_least else '≤'} {bound:g}: {'met' if met else 'missed'}"


def _main_rows(runs: dict[str, Any], floor: dict[str, float]) -> list[Row]:
    table = []
    for name, label in (("cold", "main command, cold (own clock)"), ("warm", "main command, warm (own clock)")):
        if name in runs:
            seconds, bound = runs[name]["own_clock"], floor.get(f"{name}_floor")
            beside = f"{bound:.1f} s (ratio {seconds / bound:.2f})" if bound else "–"
            table.append((label, f"{seconds:.1f} s", beside, _goal(seconds, GOALS[name])))
    if "small" in runs:
        wall = runs["small"]["wall"]
        table.append(("50 samples, cold (wall)", f"{wall:.1f} s", "–", _goal(wall, GOALS["small"])))
    return table


def _clone_rows(runs: dict[str, Any]) -> list[Row]:
    table = []
    labels = (("clone_main", "the README's main command, fresh clone (own clock)", "cold"),
              ("clone_tests", "the README's test command, fresh clone (test time)", "tests"))  # fmt: skip
    for name, label, goal_name in labels:
        if name in runs:
            ran = runs[name]
            minutes, seconds = divmod(round(ran["wall"]), 60)
            figure = f"{ran['own_clock']:.1f} s" if ran["own_clock"] else "no clock printed"
            if "pytest_runs" in ran["notes"]:
                figure += " (" + " + ".join(f"{part:.1f}" for part in ran["notes"]["pytest_runs"]) + ")"
            figure += f", exit {ran['returncode']}, {minutes} min {seconds} s with the install"
            if ran["own_clock"] and ran["returncode"] == 0:
                met = _goal(ran["own_clock"], GOALS[goal_name])
            else:
                met = f"exit 0 and ≤ {GOALS[goal_name]:g}: missed"
            table.append((label, figure, "–", met))
    return table


def _bench_rows(bench: dict[str, dict[str, float]]) -> list[Row]:
    table = []
    for env, ratio in bench.items():
        if env.endswith("(pybullet)"):  # the goal is PyBullet's; MuJoCo's ratio is in the log
            spread = (
                f" (rounds {ratio['low']:.2f}–{ratio['high']:.2f}×, median {ratio['median']:.2f}×)"
                if "low" in ratio
                else ""
            )
            figure = f"{ratio['best']:.2f}×{spread}"
            table.append((f"{env} / panda-gym", figure, "–", _goal(ratio["best"], GOALS["bench"], True)))
    return table


def _test_rows(runs: dict[str, Any], cores: int) -> list[Row]:
    tests = [runs[name] for name in sorted(runs) if name.startswith("tests")]
    if not tests:
        return []
    seconds = sum(test["own_clock"] for test in tests)
    parts = " + ".join(f"{test['own_clock']:.1f}" for test in tests)
    # The main suite keeps every core busy, so its CPU over the cores bounds its test time from below; the
    # real-time suite is paced by the arm's periods, not by its CPU, and has no such floor.
    beside = f"main suite's CPU / {cores} cores: {tests[0]['cpu'] / cores:.1f} s"
    peak = max(test["peak_gb"] for test in tests)
    return [
        ("the README's test runs (test time)", f"{seconds:.1f} s ({parts})", beside, _goal(seconds, GOALS["tests"])),
        ("their largest process", f"{peak:.2f} GB", "–", _goal(peak, GOALS["tests_peak_gb"])),
    ]


def _rehearsal_rows(runs: dict[str, Any]) -> list[Row]:
    table = []
    rehearsal = {"rehearsal_sim": "`real --connection sim`, 2 busy", "rehearsal_dry_run": "`real --dry-run`, 2 busy"}
    for name, label in rehearsal.items():
        if name in runs:
            code, late = runs[name]["returncode"], runs[name]["notes"].get("late_periods")
            said = f"late {late[0]} of {late[1]} (worst {late[2]:.1f} ms)" if late else "no late-periods line"
            met = "met" if code == 0 and late is not None else "missed"
            table.append((label, f"exit {code}, {said}", "–", f"exit 0, late periods reported: {met}"))
    return table


def rows(found: dict[str, Any]) -> list[Row]:
    """The table: each measure, its figure, its floor (and the figure's ratio to it) and its goal, met or not."""
    runs = found["runs"]
    return [
        *_main_rows(runs, found.get("floor", {})),
        *_clone_rows(runs),
        *_bench_rows(found.get("bench", {})),
        *_test_rows(runs, found["machine"]["cpus"]),
        *_rehearsal_rows(runs),
    ]


#: ``late periods 4 of 1875 (worst 14.8 ms)``, as `snac-gym real` reports a run's missed deadlines.
_LATE_PERIODS = re.compile(r"late periods\s+(\d+) of (\d+) \(worst ([0-9.]+) ms(?:, \d+ stalled)?\)")


def late_periods(output: str) -> tuple[int, int, float] | None:
    """The late periods `snac-gym real` reported (late, of all, the worst in ms), or ``None`` where it said none."""
    found = _LATE_PERIODS.findall(output)
    return (int(found[-1][0]), int(found[-1][1]), float(found[-1][2])) if found else None


def rehearsals(script: Path, out: Path, busy: int = 2) -> dict[str, Run]:
    """`snac-gym real`'s two rehearsals, each beside ``busy`` processes that keep a core busy (``yes``): the simulated
    arm (``--connection sim``), and the dry run against the emulated UR controller on this host's standard ports
    (``--dry-run``: it computes each command and sends none). Each must finish, exit 0, and report its late periods."""
    from snac_gym.real.emulator.process import EmulatorProcess

    runs = {}
    hogs = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(busy)]
    try:
        command = [str(script), "real", "--connection", "sim", "--out", str(out / "rehearsal_sim")]
        runs["rehearsal_sim"] = run("rehearsal_sim", command, out, check=False)
        with EmulatorProcess(series="cb", host="127.0.0.1", bind_timeout=90.0):
            command = [str(script), "real", "--dry-run", "--host", "127.0.0.1", "--out", str(out / "rehearsal_dry")]
            runs["rehearsal_dry_run"] = run("rehearsal_dry_run", command, out, check=False)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    for name, result in runs.items():
        result.notes["late_periods"] = late_periods((out / f"{name}.log").read_text(encoding="utf-8"))
    return runs


def fresh_clone(out: Path, tests: bool) -> dict[str, Run]:
    """The README's main command (and with ``tests`` its test command) exactly as written, each block in ``bash`` in
    a new clone of HEAD with every cache at a new folder; the clone is removed at exit."""
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout  # fmt: skip
    if dirty.strip():
        print("note: the working tree has uncommitted changes; the clone holds HEAD without them")
    folder = Path(tempfile.mkdtemp(prefix="first-hour-clone-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    clone = folder / "snac-gym"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True,
                          check=True).stdout.strip()  # fmt: skip
    readme = (clone / "README.md").read_text(encoding="utf-8")
    runs = {}
    blocks = {"clone_main": "main-command", **({"clone_tests": "test-command"} if tests else {})}
    for name, marker in blocks.items():
        caches = cold_caches()
        runs[name] = run(name, ["bash", "-c", readme_command(readme, marker)], out, caches, check=False, cwd=clone)
        runs[name].notes["commit"] = head
    if runs["clone_main"].returncode == 0:
        note_changed_cells(runs["clone_main"], clone / "runs" / "table1")
    return runs


def note_changed_cells(result: Run, folder: Path) -> None:
    """Note in ``result`` how many cells of ``folder``'s ``summary.csv`` differ from the kept Table I's."""
    changed, compared = changed_cells(folder, KEPT_TABLE)
    result.notes["summary_cells_changed"] = f"{changed} of {compared} against {KEPT_TABLE.relative_to(ROOT)}"


def compare_summaries(out: Path, runs: dict[str, Run]) -> None:
    """Note in the cold and the warm run how many of their ``summary.csv`` cells differ from the kept Table I's, and
    in the warm run how many from the cold run's: Table I's rows must not move with a cache or a machine."""
    for name in ("cold", "warm"):
        note_changed_cells(runs[name], out / name)
    changed, compared = changed_cells(out / "warm", out / "cold" / "summary.csv")
    runs["warm"].notes["summary_cells_changed_from_cold"] = f"{changed} of {compared}"


def report(table: list[Row], runs: dict[str, Run]) -> None:
    print("| measure | figure | floor | goal |\n|---|---|---|---|")
    for row in table:
        print("| " + " | ".join(row) + " |")
    for name, result in runs.items():
        for key, value in result.notes.items():
            print(f"{name}: {key.replace('_', ' ')}: {value}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="a new folder for the runs, their logs and the table")
    parser.add_argument("--bench", action="store_true", help="also `snac-gym bench` (about 3 min on 2 cores)")
    parser.add_argument("--tests", action="store_true", help="also the README's two test runs (5-10 min)")
    parser.add_argument("--rehearsal", action="store_true", help="also `snac-gym real`'s rehearsals beside busy cores")
    parser.add_argument(
        "--fresh-clone", action="store_true", help="also the README's main command (with --tests its test command) "
        "exactly as written, install included, in a new clone of HEAD"
    )  # fmt: skip
    parser.add_argument("--no-floor", action="store_true", help="skip the floor (1-3 min of one core)")
    parser.add_argument("--no-main", action="store_true", help="skip the main command's runs (and so their floor)")
    args = parser.parse_args()
    script = Path(sys.executable).with_name("snac-gym")
    if not script.is_file():
        raise SystemExit(f"no installed console script at {script}: install the project into this Python's venv")
    if args.out.exists():
        raise SystemExit(f"--out {args.out} exists: give a new folder (each run writes its own subfolder there)")
    args.out.mkdir(parents=True)
    sys.path.insert(0, str(ROOT))  # the project's modules where it is not installed in this venv's site-packages
    from snac_gym.common.machine import describe_machine, machine_info

    machine = machine_info()
    print(describe_machine(machine))
    runs: dict[str, Run] = {}
    if not args.no_main:
        cold = cold_caches()
        runs["cold"] = run("cold", [str(script), *MAIN, "--out", str(args.out / "cold")], args.out, cold)
        runs["warm"] = run("warm", [str(script), *MAIN, "--out", str(args.out / "warm")], args.out, cold)
        runs["small"] = run("small", [str(script), *SMALL, "--out", str(args.out / "small")], args.out, cold_caches())
        compare_summaries(args.out, runs)
    found: dict[str, Any] = {"machine": machine}
    if args.bench:
        bench = run("bench", [str(script), "bench"], args.out)
        found["bench"] = bench_ratios((args.out / "bench.log").read_text(encoding="utf-8"))
        runs["bench"] = bench
    if args.tests:
        for index, words in enumerate(readme_pytest_commands((ROOT / "README.md").read_text(encoding="utf-8")), 1):
            runs[f"tests{index}"] = run(f"tests{index}", [sys.executable, *words], args.out)
    if args.rehearsal:
        runs.update(rehearsals(script, args.out))
    if args.fresh_clone:
        runs.update(fresh_clone(args.out, args.tests))
    if not (args.no_floor or args.no_main):
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from table1_floor import floor

        print(
            f"{time.strftime('%H:%M:%S')} floor: docs/scripts/table1_floor.py {args.out / 'cold'} {args.out / 'warm'}"
        )
        found["floor"] = floor(args.out / "cold", args.out / "warm")
    found["runs"] = {name: asdict(result) for name, result in runs.items()}
    table = rows(found)
    found["table"] = table
    (args.out / "first_hour.json").write_text(json.dumps(found, indent=2) + "\n", encoding="utf-8")
    print(f"\n{describe_machine(machine)}\n")
    report(table, runs)


if __name__ == "__main__":
    main()
