"""Score two controllers on a few random samples of both tasks, as Table I does.

    python examples/compare_controllers.py [SAMPLES] [OUT]        # default 20 samples per task, runs/compare

The evaluator matches every controller's effort to SNAC's (the mean over samples of each rollout's peak
|u|/limit), runs each sample on the exact kinematic model and writes results.csv, summary.md and box plots
into OUT. A controller below the success threshold is marked: its cost is no merit if it does not do the task. The full
Table I is ``snac-gym evaluate --out runs/table1`` (1000 samples per task, every controller; docs/table1.md).
"""

import sys
from pathlib import Path

from snac_gym.evaluation import EvaluationConfig, run_evaluation


def main(samples: int = 20, out: str = "runs/compare") -> None:
    # effort_samples=0: equal effort matched on these few samples (quick); Table I matches on 1000.
    config = EvaluationConfig(
        out=Path(out), controllers=("snac", "dls"), samples=samples, effort_samples=0, workers=1, progress=False
    )
    results = run_evaluation(config)
    table = results.groupby(["task", "controller"]).agg(
        samples=("sample", "size"),
        success=("success", "mean"),
        V=("cost", "mean"),
        final_error_mm=("final_error", lambda e: 1e3 * e.median()),
    )
    table["verdict"] = ["" if rate >= config.success_threshold else "FAILS the task" for rate in table["success"]]
    print(table.reset_index().round(3).to_string(index=False))
    print(f"summary: {Path(out) / 'summary.md'}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20, *sys.argv[2:3])
