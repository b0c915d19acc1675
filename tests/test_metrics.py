"""The first command's jump from rest: the metrics' ``first_jump_cost``/``first_jump_share`` and
the summary's share of V/N that it is, against computations that do not go through them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation

from snac_gym.control.cost import CostConvention, trajectory_cost
from snac_gym.metrics import METRIC_COLUMNS, rollout_metrics
from snac_gym.rollout import Rollouts

DT = 1.0 / 125.0
STEPS = 6


def _rollouts(commands: np.ndarray, errors: np.ndarray) -> Rollouts:
    batch = len(commands)
    return Rollouts(
        DT,
        np.arange(STEPS) * DT,
        None,
        commands,
        None,
        errors * 0,
        errors * 0,
        errors,
        np.zeros((batch, 6)),
        np.zeros((batch, 3)),
        np.zeros((batch, 3)),
    )


@pytest.fixture(scope="module")
def rollout():
    """Two rollouts whose first commands are known: a full-speed start and a gentle one."""
    rng = np.random.default_rng(7)
    errors = rng.normal(scale=0.05, size=(2, STEPS, 3))
    commands = rng.normal(scale=0.1, size=(2, STEPS, 6))
    commands[0, 0] = [2.0, -2.0, 3.0, 0.0, 0.0, 1.0]  # ‖u₀‖² = 18
    commands[1, 0] = [0.01, 0.0, 0.0, 0.0, 0.0, 0.0]  # ‖u₀‖² = 1e-4
    return _rollouts(commands, errors), errors, commands


def _metrics(rollouts: Rollouts, convention: CostConvention | None = None) -> pd.DataFrame:
    return rollout_metrics(rollouts, "reach", np.full(6, 10.0), convention)


def test_the_columns_are_the_documented_ones(rollout):
    rows = _metrics(rollout[0])
    assert tuple(rows.columns) == METRIC_COLUMNS
    import snac_gym.metrics

    for column in ("first_jump_cost", "first_jump_share"):
        assert f"\n{column} " in snac_gym.metrics.__doc__


def test_first_jump_cost_is_the_first_commands_squared_norm_over_dt(rollout):
    rollouts, errors, commands = rollout
    rows = _metrics(rollouts)
    # (u₀ − 0)/Δt squared, held for Δt: ‖u₀‖²/Δt, i.e. 125·‖u₀‖²
    np.testing.assert_allclose(rows["first_jump_cost"], [18.0 / DT, 1e-4 / DT], rtol=1e-12)
    assert rows["first_jump_cost"].iloc[0] == pytest.approx(125.0 * 18.0, rel=1e-12)
    np.testing.assert_allclose(rows["first_jump_share"], rows["first_jump_cost"] / rows["cost"], rtol=1e-12)
    # the full-speed start pays about half its V at step 0 (the other half: the drop back at step 1)
    assert rows["first_jump_share"].iloc[0] > 0.4 > 10 * rows["first_jump_share"].iloc[1]


def test_cost_less_the_jump_is_the_cost_with_no_jump_from_rest(rollout):
    rollouts, errors, commands = rollout
    rows = _metrics(rollouts)
    without = rows["cost"] - rows["first_jump_cost"]
    # u₋₁ = u₀ through the cost function itself, and through the metrics under that convention
    np.testing.assert_allclose(without, trajectory_cost(errors, commands, DT, initial_command=commands[:, 0]).total)
    np.testing.assert_allclose(without, _metrics(rollouts, CostConvention(udot_start="first"))["cost"], rtol=1e-12)


@pytest.mark.parametrize("convention", [CostConvention(udot_start="first"), CostConvention(cost="hjb")])
def test_no_jump_where_the_convention_has_none(rollout, convention):
    rows = _metrics(rollout[0], convention)
    assert (rows["first_jump_cost"] == 0).all() and (rows["first_jump_share"] == 0).all()


def test_a_rollout_that_never_moves_has_share_zero_not_nan():
    rows = _metrics(_rollouts(np.zeros((1, STEPS, 6)), np.zeros((1, STEPS, 3))))
    assert rows["cost"].iloc[0] == 0 and rows["first_jump_share"].iloc[0] == 0


SMALL = {
    "controllers": ("dls", "lqr"),
    "samples": 3,
    "effort_samples": 0,
    "match_effort": False,
    "horizons": {"reach": 0.2, "track": 0.2},
    "progress": False,
    "plots": False,
}


def test_the_summary_shows_the_share_of_vn_that_is_the_jump(tmp_path):
    config = EvaluationConfig(out=tmp_path / "rest", **SMALL)
    results = run_evaluation(config)
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    for (task, controller), part in results.groupby(["task", "controller"]):
        share = 100 * part["first_jump_cost"].sum() / part["cost"].sum()
        assert summary.loc[controller, f"{task}_first_jump_percent"] == pytest.approx(share, rel=1e-9)
        without = summary.loc[controller, f"{task}_cost_without_first_jump"]
        assert without == pytest.approx(part["cost_table1_first"].mean(), rel=1e-9)
    text = (config.out / "summary.md").read_text()
    assert "| jump share |" in text and "Jump share: the part of V/N" in text
    dls = summary.loc["dls", "reach_first_jump_percent"]
    assert f"| {dls:.1f} % |" in text


def test_the_summary_leaves_the_share_out_where_the_cost_has_no_jump(tmp_path):
    config = EvaluationConfig(out=tmp_path / "hjb", cost="hjb", **SMALL)
    run_evaluation(config)
    summary = pd.read_csv(config.out / "summary.csv")
    assert not any("first_jump" in column for column in summary.columns)
    assert "jump share" not in (config.out / "summary.md").read_text()


@pytest.mark.parametrize("width", range(10))
def test_the_logs_norms_are_numpys_bit_for_bit(width):
    """The rows' norms (‖eₖ‖, ‖uₖ‖ of every step) added column by column are ``np.linalg.norm`` exactly, over
    magnitudes from 1e-9 to 1e9 and through NaN, inf and signed zeros; from width 8 on NumPy's own is used."""
    from snac_gym.metrics import _vector_norms

    rng = np.random.default_rng(width)
    logs = rng.standard_normal((40, 300, width)) * 10.0 ** rng.integers(-9, 10, (40, 300, width))
    if width:
        logs[0, :4, 0] = [np.nan, np.inf, -np.inf, -0.0]
    with np.errstate(over="ignore"):
        np.testing.assert_array_equal(_vector_norms(logs), np.linalg.norm(logs, axis=-1))
        np.testing.assert_array_equal(_vector_norms(logs[0, 0]), np.linalg.norm(logs[0, 0]))
        np.testing.assert_array_equal(_vector_norms(logs[:, ::-2]), np.linalg.norm(logs[:, ::-2], axis=-1))  # a view
    finite = np.clip(logs[1:3, :3], -1e9, 1e9)  # integers and complex numbers go to NumPy's own norm
    for other in (logs.astype(np.float32), np.rint(finite).astype(np.int64), finite * (1 + 2j)):
        with np.errstate(over="ignore", invalid="ignore"):
            np.testing.assert_array_equal(_vector_norms(other), np.linalg.norm(other, axis=-1))
