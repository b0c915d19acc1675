"""The README's and docs' Table I claims are the text tools/claims.py writes from the kept main-command summary."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def claims():
    spec = importlib.util.spec_from_file_location("claims", ROOT / "tools" / "claims.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_readme_and_docs_say_what_the_kept_summary_says(claims, capsys):
    assert claims.main(["--check"]) == 0, capsys.readouterr().err
    blocks = {m["name"] for path in claims.TARGETS for m in claims._BLOCK.finditer(path.read_text())}
    assert blocks == set(claims.BLOCKS)  # every writer has its place, and nothing else is marked


def test_an_edited_number_in_a_block_fails_the_check_naming_it(claims, tmp_path, monkeypatch, capsys):
    readme = tmp_path / "README.md"
    shutil.copyfile(claims.TARGETS[0], readme)
    text = readme.read_text()
    assert "1.8e-19" in text
    readme.write_text(text.replace("1.8e-19", "1.8e-41", 1))
    monkeypatch.setattr(claims, "ROOT", tmp_path)
    monkeypatch.setattr(claims, "TARGETS", (readme,))
    assert claims.main(["--check"]) == 1
    assert "README.md: table1" in capsys.readouterr().err
    assert readme.read_text().count("1.8e-41") == 1  # --check writes nothing


def test_the_p_value_sentence_bounds_every_p_of_the_data(claims):
    summary = claims.read_summary()
    ps = summary[[f"{t}_vs_best_wilcoxon_p" for t in claims.TASKS]].to_numpy().ravel()
    ps = ps[~pd.isna(ps)]
    sentence = claims.table1_p(summary)
    bound = float(sentence.split("p < ")[1].split(";")[0])
    assert (ps < bound).all() and ps.max() >= bound / 10
    assert f"{ps.max():.1e}" in sentence


@pytest.mark.parametrize(("values", "text"), [
    ((0.00231, 0.00219, 0.00234), "0.0023 [0.0022, 0.0023]"),
    ((1.4349, 1.40, 1.458), "1.43 [1.40, 1.46]"),
    ((1.0101, 1.0098, 1.0103), "1.010 [1.010, 1.010]"),
    ((0.7403, 0.7226, 0.7555), "0.74 [0.72, 0.76]"),
])  # fmt: skip
def test_ratios_keep_the_digits_that_tell_them_apart(claims, values, text):
    assert claims._ratio(values) == text
