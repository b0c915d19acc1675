"""The README's and docs' statements about Table I, written from the main command's results, never by hand.

The main command's ``summary.csv`` is kept in ``docs/data/table1/`` with what made it (``source.json``). Every
block between ``<!-- claims:NAME -->`` and ``<!-- /claims:NAME -->`` in the files of :data:`TARGETS` is the text
:func:`render` writes from that file: Table I's rows, the paired statistics (median ratios, their intervals, the
shares, the Wilcoxon p-values) and the sentence saying what the reference is.

Usage:
    python tools/claims.py --from runs/table1   # keep that run's summary, then write every block
    python tools/claims.py                      # write every block from the kept summary
    python tools/claims.py --check              # exit 1 naming each block that differs
                                                # (tests/integration/test_claims.py)
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs" / "data" / "table1"
#: The files whose claims blocks are written here.
TARGETS = (ROOT / "README.md", ROOT / "docs" / "table1.md")
MAIN_COMMAND = "snac-gym evaluate --out runs/table1 --workers 2 --controllers snac,snac-hjb,lqr,rnn,svf,dls,ppo,optimal"
TASKS = ("reach", "track")
TASK_WORDS = {"reach": "regulation", "track": "tracking"}
#: The README's row labels: the paper's names with their source.
README_LABELS = {
    "optimal": "Optimal (open-loop reference)",
    "snac": "SNAC (paper's defaults)",
    "rnn": "RNN (Li et al.)",
    "svf": "SVF (Colomé, Torras)",
    "dls": "DLS",
    "ppo": "PPO",
}
_BLOCK = re.compile(r"(<!-- claims:(?P<name>[a-z0-9-]+) -->\n)(?P<body>.*?)(<!-- /claims:(?P=name) -->)", re.S)


def _percent(share: float) -> str:
    """A share as the README prints it: one decimal (``98.0 %``, ``9.7 %``), none at 0 and 100 %."""
    return f"{100 * share:.0f} %" if share in (0.0, 1.0) else f"{100 * share:.1f} %"


def _ratio(values: tuple[float, float, float]) -> str:
    """``median [low, high]``: 2 decimals; 3 within 2 % of 1, where the third is the difference; 2 significant
    digits below 0.1."""
    median, low, high = values
    if median < 0.1:
        digits = max(2, 1 - math.floor(math.log10(median)))
    else:
        digits = 3 if abs(median - 1.0) < 0.02 else 2
    return f"{median:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _best(summary: pd.DataFrame, task: str) -> str:
    return str(summary[f"{task}_vs_best"].dropna().iloc[0])


def _label(controller: str) -> str:
    return README_LABELS.get(controller, controller)


def table1(summary: pd.DataFrame) -> str:
    """README's Table I, after the paragraph that reads it: V/N, jump share, success and the paired
    comparison with the task's best."""
    best = {task: _best(summary, task) for task in TASKS}
    threshold = {"reach": "≤ 1 mm", "track": "≤ 5 mm"}
    header = ["Controller"]
    for task in TASKS:
        word = TASK_WORDS[task].capitalize()
        header += [
            f"{word} V/N",
            "jump share",
            f"success ({threshold[task]})",
            f"vs best ({_label(best[task]).split(' (')[0]})",
        ]
    intro = (
        "The main command above (seed 0, kinematic engine, 12 s / 20 s horizons, every controller matched to SNAC's "
        'mean peak |u|/limit; V/N: the paper\'s trajectory cost per sample, u̇ term included, u₋₁ = 0). "vs best": '
        "paired with the task's cheapest controller that does the task, the median cost ratio [bootstrap 95 % CI] "
        "and the share of samples where it costs less " + table1_p(summary)
    )
    lines = [
        _wrapped(intro).rstrip("\n"),
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for _, row in summary.iterrows():
        cells = [_label(row["controller"])]
        for task in TASKS:
            cost = f"{row[f'{task}_cost']:.2f}"
            cells.append(f"**{cost}**" if row["controller"] == best[task] else cost)
            cells.append(_percent(row[f"{task}_first_jump_percent"] / 100))
            fails = "" if row[f"{task}_qualified"] or row["controller"] == "optimal" else " (**fails**)"
            cells.append(_percent(row[f"{task}_success_rate"]) + fails)
            if pd.isna(row[f"{task}_vs_best_median_ratio"]):
                cells.append("—")
            else:
                ratio = _ratio(tuple(row[f"{task}_vs_best_{k}"] for k in ("median_ratio", "ci_low", "ci_high")))
                cells.append(f"{ratio}, {_percent(row[f'{task}_vs_best_fraction_better'])}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _largest_p(summary: pd.DataFrame) -> tuple[float, str, str]:
    """The largest Wilcoxon p of any row against its task's best: (p, controller, task)."""
    found = [
        (float(row[f"{task}_vs_best_wilcoxon_p"]), str(row["controller"]), task)
        for task in TASKS
        for _, row in summary.iterrows()
        if not pd.isna(row[f"{task}_vs_best_wilcoxon_p"])
    ]
    return max(found)


def table1_p(summary: pd.DataFrame) -> str:
    """The sentence on the paired tests' p-values."""
    p, controller, task = _largest_p(summary)
    bound = math.ceil(math.log10(p))
    return (
        f"(every Wilcoxon signed-rank p < 1e{bound}; {_label(controller)} against {_label(_best(summary, task))} "
        f"in {TASK_WORDS[task]} has the largest, {p:.1e}):"
    )


def table1_notes(summary: pd.DataFrame) -> str:
    """The paragraph under Table I: who fails, how much of V/N the first jump is, and what the reference is."""
    rows = summary.set_index("controller")
    contestants = rows.drop(index="optimal")
    failing = [c for c in contestants.index if not all(contestants.loc[c, f"{t}_qualified"] for t in TASKS)]
    jumps = [
        contestants.loc[c, f"{t}_first_jump_percent"] for c in contestants.index if c not in failing for t in TASKS
    ]
    above_90 = sum(j > 90 for j in jumps)
    below = int(sum(contestants[f"{t}_below_optimal"].sum() for t in TASKS))
    samples = int(sum(rows.loc["optimal", f"{t}_n"] for t in TASKS))
    fails = " and ".join(_label(c).split(" (")[0] for c in failing) or "No controller"
    verb = "fail" if len(failing) > 1 else "fails"
    beats = (
        f"no controller that keeps the limits beats it on any of the {samples} samples"
        if below == 0
        else (f"a controller that keeps the limits beats it on {below} of the {samples} samples")
    )
    text = (
        f"{fails} {verb} the task at its defaults and costs less only because of that; a failing controller is never\n"
        f"ranked. The first command's jump from rest is {min(jumps):.0f}–{max(jumps):.0f} % of a passing "
        f"controller's V/N\n(**jump share**; over 90 % in {above_90} of {len(jumps)} rows), so "
        "Table I ranks them by their first command ([docs/table1.md](docs/table1.md)). The optimum is\n"
        + reference(summary)
        + ", inside the joint and velocity limits; "
        + beats
        + "\n"
        "([docs/optimality.md](docs/optimality.md#the-reference-on-held-out-samples))."
    )
    return _wrapped(text)


def _wrapped(text: str) -> str:
    return textwrap.fill(" ".join(text.split()), width=118, break_long_words=False, break_on_hyphens=False) + "\n"


def _feedback_starts() -> str:
    """How many feedback laws the reference starts from, in words (its ``OWN_STARTS``)."""
    from snac_gym.evaluation.reference.optimum import OWN_STARTS

    return {1: "one", 2: "two", 3: "three", 4: "four"}.get(len(OWN_STARTS), str(len(OWN_STARTS)))


def reference(summary: pd.DataFrame) -> str:
    """What the reference is, from its own columns (its starts: reference.json) and its certificate."""
    optimal = summary.set_index("controller").loc["optimal"]
    starts = json.loads((DATA / "reference.json").read_text())
    counts = sorted({n for task in TASKS for n in starts[task]["starts_per_sample"]})
    count = f"{counts[0]}–{counts[-1]}" if len(counts) > 1 else str(counts[0])
    one = [100 * starts[task]["one_optimum_share"] for task in TASKS]
    basins = (
        "one local optimum on every sample"
        if min(one) == 100
        else f"one local optimum on {one[0]:.1f} % / {one[1]:.1f} % of the samples"
    )
    median = "/".join(f"{optimal[f'{task}_optimal_bound_ratio_median']:.1f}" for task in TASKS)
    p95 = "/".join(f"{optimal[f'{task}_optimal_bound_ratio_p95']:.1f}" for task in TASKS)
    return (
        f"the best of {count} contestant-free starts per sample (rest, {_feedback_starts()} feedback laws, IK branches "
        f"and random in-limit configurations; {basins}), within a median {median}× "
        f"(95th percentile {p95}×, regulation/tracking) of a certified lower bound"
    )


def paired(task: str) -> Callable[[pd.DataFrame], str]:
    def write(summary: pd.DataFrame) -> str:
        # the evaluator's own paired table, as its summary.md prints it
        from snac_gym.evaluation.reports.writer import paired_lines

        lines = paired_lines(summary, [task])
        start = next(i for i, line in enumerate(lines) if line.startswith("| Controller"))
        return "\n".join(lines[start:]) + "\n"

    return write


#: Each block's writer.
BLOCKS: dict[str, Callable[[pd.DataFrame], str]] = {
    "table1": table1,
    "table1-notes": table1_notes,
    "paired-reach": paired("reach"),
    "paired-track": paired("track"),
}


def read_summary(folder: Path = DATA) -> pd.DataFrame:
    summary = pd.read_csv(folder / "summary.csv")
    for task in TASKS:
        if not (summary[f"{task}_n"] == 1000).all():
            raise SystemExit(f"{folder / 'summary.csv'}: not the main command's 1000 samples per task")
    return summary


def keep(run: Path) -> None:
    """Keep ``run``'s summary, its reference's starts and what made it."""
    DATA.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run / "summary.csv", DATA / "summary.csv")
    results = pd.read_parquet(run / "results.parquet")
    starts = {}
    for task in TASKS:
        rows = results[(results["controller"] == "optimal") & (results["task"] == task)]
        solved = rows["optimal_starts"].to_numpy()  # solved to the end; the others were screened into their basin
        starts[task] = {
            "starts_per_sample": sorted({int(n) for n in solved + rows["optimal_same_basin"].to_numpy()}),
            # local optima within the solver's tolerance of each other are one
            "one_optimum_share": float(((solved == 1) | (rows["optimal_local_spread"].to_numpy() <= 1e-6)).mean()),
            "spread_max": float(rows["optimal_local_spread"].max()),
        }
    (DATA / "reference.json").write_text(json.dumps(starts, indent=2) + "\n")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    source = {
        "command": MAIN_COMMAND,
        "commit": commit,
        "versions": {name: version(name) for name in ("snac-gym", "numpy", "scipy", "pin", "numba")},
        "note": "written by tools/claims.py --from RUN; the README's and docs' claims blocks are rendered from "
        "summary.csv",
    }
    (DATA / "source.json").write_text(json.dumps(source, indent=2) + "\n")


def rendered(text: str, summary: pd.DataFrame, path: Path) -> str:
    def replace(match: re.Match[str]) -> str:
        name = match["name"]
        if name not in BLOCKS:
            raise SystemExit(f"{path.relative_to(ROOT)}: unknown claims block {name!r} (known: {sorted(BLOCKS)})")
        return match.group(1) + BLOCKS[name](summary) + match.group(4)

    return _BLOCK.sub(replace, text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="run", type=Path, help="a main-command run folder to keep first")
    parser.add_argument("--check", action="store_true", help="exit 1 if a block differs from its data")
    args = parser.parse_args(argv)
    if args.run is not None:
        read_summary(args.run)
        keep(args.run)
    summary = read_summary()
    stale = []
    for path in TARGETS:
        text = path.read_text()
        new = rendered(text, summary, path)
        if new == text:
            continue
        if args.check:
            old_blocks = {m["name"]: m["body"] for m in _BLOCK.finditer(text)}
            new_blocks = {m["name"]: m["body"] for m in _BLOCK.finditer(new)}
            stale += [f"{path.relative_to(ROOT)}: {n}" for n in new_blocks if old_blocks.get(n) != new_blocks[n]]
        else:
            path.write_text(new)
    if stale:
        print(
            "claims not generated from docs/data/table1/summary.csv: "
            + "; ".join(stale)
            + " (run python tools/claims.py)",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
