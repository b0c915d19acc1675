"""The paper's quantitative test: random samples, the trajectory cost and the reports. This folder installs as
``snac_gym.evaluation`` (subpackages by job: ``execution``, ``effort``, ``reference``, ``reports``).

``run_evaluation(EvaluationConfig(out=...))`` runs it from Python; ``snac-gym evaluate`` from
the shell. See docs/evaluation.md.
"""

if (
    __name__ == "evaluation"
):  # this folder imported as a top-level package (from the repository's root, or an old import)
    raise ImportError(
        "snac-gym's evaluation package is imported as snac_gym.evaluation since 0.2.0 "
        "(`from snac_gym.evaluation import ...`); the top-level name `evaluation` is no longer installed"
    )

from snac_gym.evaluation.run_config import DEFAULT_HORIZONS, EvaluationConfig
from snac_gym.evaluation.runner import run_evaluation

__all__ = ["DEFAULT_HORIZONS", "EvaluationConfig", "run_evaluation"]
