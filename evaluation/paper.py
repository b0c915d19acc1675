"""The paper's Table I, for the reports to print beside the measured values.

Values are the normalised trajectory cost V/N of Section V ("Quantitative Test Comparison"),
1000 regulation samples and 1000 feasible ellipses on a kinematic UR10 model, Q = I₃, R = I₆,
all controllers tuned to the same maximum control effort.
"""

from __future__ import annotations

#: Table I of the paper, rows in the paper's order: controller name in snac-gym → {task: V/N}.
PAPER_TABLE_I: dict[str, dict[str, float]] = {
    "rnn": {"reach": 49.74, "track": 14.39},
    "svf": {"reach": 48.32, "track": 32.21},
    "snac": {"reach": 5.78, "track": 3.30},
}

#: Row labels: the paper's for its controllers; DLS and PPO are not in the paper.
PAPER_LABELS: dict[str, str] = {
    "rnn": "RNN",
    "svf": "SVF",
    "snac": "Proposed (SNAC)",
    "dls": "DLS",
    "ppo": "PPO",
    "optimal": "Optimal (open-loop reference, whole reference known)",
}

#: Column labels of Table I for each task.
TASK_LABELS: dict[str, str] = {"reach": "Regulation", "track": "Tracking"}


def paper_value(controller: str, task: str) -> float | None:
    """Table I's V/N for ``controller`` on ``task``, or ``None`` if the paper has no such entry."""
    return PAPER_TABLE_I.get(controller, {}).get(task)


def controller_label(controller: str) -> str:
    """The row label of a controller: the paper's where it has one, else the registry name."""
    return PAPER_LABELS.get(controller, controller)
