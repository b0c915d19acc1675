"""``snac-gym plot``: a demo's or a real run's figures drawn again from its log, as the run draws them."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.apps.demo import run_demo
from snac_gym.apps.figures import redraw_figures, run_log
from snac_gym.apps.real import run_real_episode

runner = CliRunner()


def test_the_figures_drawn_from_a_demos_log_are_the_demos_own_byte_for_byte(tmp_path):
    drawn = run_demo(task="track", controller="snac", out_dir=tmp_path / "demo", steps=200)
    pngs = sorted(p for p in drawn.files if p.suffix == ".png")
    assert len(pngs) == 7
    result = runner.invoke(
        app, ["plot", str(tmp_path / "demo" / "track_snac_log.parquet"), "--out", str(tmp_path / "again")]
    )
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith(f"drew 7 figures in {tmp_path / 'again'}/: track_snac_path.png, ")
    assert result.stderr == f"plot: drawing 7 figures into {tmp_path / 'again'}/\n"  # said before the first is drawn
    again = sorted((tmp_path / "again").glob("*.png"))
    assert [p.name for p in again] == [p.name for p in pngs]
    for ours, theirs in zip(pngs, again):
        assert ours.read_bytes() == theirs.read_bytes(), ours.name  # the same figure, to the byte


def test_a_real_run_without_figures_gets_them_with_its_loop_timing_from_its_folder(tmp_path):
    run_real_episode(controller="dls", out_dir=tmp_path, connection="sim", steps=40, plots=False)
    assert not list(tmp_path.glob("*.png"))
    files = redraw_figures(tmp_path)  # the folder: the one log in it
    assert sorted(p.name for p in files) == sorted(
        f"reach_dls_{name}.png" for name in ("path", "error", "joint_velocities", "cost", "figure3", "timing")
    )
    assert all(p.parent == tmp_path and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in files)


def test_the_tolerance_marked_is_the_runs_summarys(tmp_path, monkeypatch):
    run_demo(task="reach", controller="dls", out_dir=tmp_path, steps=50, plots=False)
    import snac_gym.apps.plots as panels

    seen, plot_error = [], panels.plot_error

    def recorded(log, **kwargs):
        seen.append(kwargs["tolerance"])
        return plot_error(log, **kwargs)

    monkeypatch.setattr(panels, "plot_error", recorded)
    summary = tmp_path / "reach_dls_summary.json"
    summary.write_text(json.dumps({**json.loads(summary.read_text()), "tolerance": 0.004}))
    redraw_figures(tmp_path)
    summary.unlink()  # none beside the log: the task's own
    redraw_figures(tmp_path)
    assert seen == [0.004, 0.004, 0.001, 0.001]  # the error panel and Figure 3's


def test_what_is_not_one_runs_log_is_refused_in_one_line(tmp_path):
    assert runner.invoke(app, ["plot", str(tmp_path)]).output == (
        f"error: {tmp_path}/ must hold one run's log (*_log.parquet) to draw; found none\n"
    )
    for name in ("reach_snac_log.parquet", "track_snac_log.parquet"):
        (tmp_path / name).write_bytes(b"not parquet")
    two = runner.invoke(app, ["plot", str(tmp_path)])
    assert two.exit_code == 2 and "found reach_snac_log.parquet, track_snac_log.parquet" in two.output
    broken = runner.invoke(app, ["plot", str(tmp_path / "reach_snac_log.parquet")])
    assert broken.exit_code == 2
    assert re.fullmatch(
        rf"error: {re.escape(str(tmp_path))}/reach_snac_log\.parquet is not a run's log: \w+: .*\n", broken.output
    )
    (tmp_path / "track_snac_log.parquet").unlink()
    run_demo(task="reach", controller="dls", out_dir=tmp_path / "demo", steps=20, plots=False)
    (tmp_path / "demo" / "reach_dls_summary.json").write_text("{")
    with pytest.raises(
        ValueError, match=r"reach_dls_summary\.json \(the run's summary, for its tolerance\) is not JSON"
    ):
        redraw_figures(tmp_path / "demo")
    other = tmp_path / "table.parquet"
    pd.DataFrame({"a": [1.0]}).to_parquet(other)
    with pytest.raises(ValueError, match=r"table\.parquet is not a run's log: its name must end in _log\.parquet"):
        run_log(other)
    plain = tmp_path / "x_log.parquet"
    pd.DataFrame({"a": [1.0]}).to_parquet(plain)
    with pytest.raises(ValueError, match=r"x_log\.parquet is not a run's log: it has no task or dt"):
        redraw_figures(plain)


def test_an_evaluations_folder_or_a_csv_log_is_refused_with_what_to_draw_instead(tmp_path):
    """Two things a user hands plot by mistake: an evaluation's folder (rows, not a log; evaluate drew its box plots)
    and the CSV log --csv writes beside the Parquet one, which is the one plot reads."""
    evaluation = tmp_path / "eval"
    evaluation.mkdir()
    for name in ("run.json", "results.parquet"):
        (evaluation / name).write_bytes(b"{}")
    with pytest.raises(ValueError, match=r"found none \(an evaluation's folder: evaluate drew its box plots; plot "):
        run_log(evaluation)
    (evaluation / "run.json").unlink()  # not an evaluation's: the plain refusal
    with pytest.raises(ValueError, match=r"to draw; found none$"):
        run_log(evaluation)
    run_demo(task="reach", controller="dls", out_dir=tmp_path / "demo", steps=20, plots=False, csv=True)
    csv, parquet = tmp_path / "demo" / "reach_dls_log.csv", tmp_path / "demo" / "reach_dls_log.parquet"
    with pytest.raises(ValueError) as refused:
        run_log(csv)
    assert str(refused.value) == (
        f"{csv} is not a run's log: its name must end in _log.parquet; draw the Parquet log beside it: "
        f"`snac-gym plot {parquet}`"
    )
    parquet.unlink()  # nothing beside it to name
    with pytest.raises(ValueError, match=r"must end in _log\.parquet$"):
        run_log(csv)
