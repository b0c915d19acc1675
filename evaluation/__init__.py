"""The paper's quantitative test: random samples, the trajectory cost and the reports.

``run_evaluation(EvaluationConfig(out=...))`` runs it from Python; ``snac-gym evaluate`` from
the shell. See docs/evaluation.md.
"""

from evaluation.run_config import DEFAULT_HORIZONS, EvaluationConfig
from evaluation.runner import run_evaluation

__all__ = ["DEFAULT_HORIZONS", "EvaluationConfig", "run_evaluation"]
