"""The equal-effort step's status on the progress line (evaluation/effort/activity.py): the matches still running,
how many are done, and where each running one is."""

from __future__ import annotations

import re
import threading

import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.effort.activity import SHOWN, MatchActivity
from snac_gym.evaluation.execution.progress import Progress


def test_the_status_names_only_the_running_matches_each_where_it_is():
    shown: list[str] = []
    activity = MatchActivity(shown.append, 5)
    with activity.running("reach", "lqr"):
        with activity.running("reach", "mpc"):
            activity.tried("reach", "mpc")
            activity.tried("reach", "mpc")
            assert activity.text() == "matching effort (0 of 5 done): lqr on reach, starting; mpc on reach, knob try 2"
            activity.full_pass("reach", "mpc")
            assert shown[-1].endswith("mpc on reach, full pass")
        assert shown[-1] == "matching effort (1 of 5 done): lqr on reach, starting"
        activity.tried("reach", "mpc")  # a match that has ended is not shown again
        assert shown[-1] == "matching effort (1 of 5 done): lqr on reach, starting"
    assert shown[-1] == "" and activity.text() == ""


def test_a_failed_match_is_done_and_many_running_ones_are_counted_past_the_first_few():
    shown: list[str] = []
    activity = MatchActivity(shown.append, SHOWN + 3)
    with pytest.raises(RuntimeError):
        with activity.running("track", "svf"):
            raise RuntimeError("the search failed")
    assert shown[-1] == ""
    names = [f"c{i}" for i in range(SHOWN + 2)]
    entered = [activity.running("reach", name) for name in names]
    for context in entered:
        context.__enter__()
    assert shown[-1].startswith(f"matching effort (1 of {SHOWN + 3} done): c0 on reach, starting;")
    assert shown[-1].endswith("; 2 more") and shown[-1].count(" on reach") == SHOWN
    for context in entered:
        context.__exit__(None, None, None)
    assert shown[-1] == "" and f"({SHOWN + 3} of {SHOWN + 3} done)" not in "".join(shown)


def test_matches_on_several_threads_count_each_try_once():
    activity = MatchActivity(None, 4)
    barrier = threading.Barrier(4)
    seen: list[str] = []

    def search(name: str) -> None:
        with activity.running("reach", name):
            barrier.wait()
            for _ in range(500):
                activity.tried("reach", name)
            if barrier.wait() == 0:  # all four still running, every try made: one thread reads the status
                seen.append(activity.text())
            barrier.wait()

    threads = [threading.Thread(target=search, args=(f"c{i}",)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(seen) == 1 and seen[0].count("knob try 500") == SHOWN and seen[0].endswith("; 1 more"), seen
    assert activity.text() == ""


def test_a_run_that_matches_effort_shows_each_search_and_drops_it_when_done(tmp_path, monkeypatch):
    """A small run whose knobs are not shipped (12 effort samples): the status the progress line shows, in order."""
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    shown: list[str] = []
    original = Progress.status
    monkeypatch.setattr(Progress, "status", lambda self, text: (shown.append(text), original(self, text))[1])
    config = EvaluationConfig(
        out=tmp_path / "run", tasks=("reach",), horizons={"reach": 0.4}, controllers=("dls", "lqr", "svf"),
        effort_reference="dls", samples=3, effort_samples=12, chunk_size=4, progress=False, plots=False,
    )  # fmt: skip
    run_evaluation(config)
    matching = [text for text in shown if text.startswith("matching effort")]
    assert matching[0] == "matching effort (0 of 2 done): lqr on reach, starting"
    for name in ("lqr", "svf"):
        tries = [int(m.group(1)) for t in matching if (m := re.search(rf"{name} on reach, knob try (\d+)", t))]
        assert tries and tries == list(range(1, len(tries) + 1)), matching  # every try shown, in order
        assert any(f"{name} on reach, full pass" in text for text in matching)
    # Serial (one worker): lqr's match ends before svf's starts, and is not named after it.
    first_svf = next(i for i, text in enumerate(matching) if "svf" in text)
    assert matching[first_svf] == "matching effort (1 of 2 done): svf on reach, starting"
    assert all("lqr" not in text for text in matching[first_svf:])
    assert shown[shown.index(matching[-1]) + 1] == ""  # cleared when the last match ends
