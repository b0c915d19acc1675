"""Every results part is stored with its SHA-256: a resumed run redoes a damaged part instead of reading it,
and a part damaged after it was written is refused when read."""

from __future__ import annotations

import dataclasses

import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.store import RunDirectoryError, RunStore, checksum_path, part_is_intact

SMALL = {"samples": 4, "tasks": ("reach",), "horizons": {"reach": 0.3}, "controllers": ("dls", "lqr"),
         "match_effort": False, "chunk_size": 2, "progress": False, "plots": False}  # fmt: skip


def _flip_one_bit(path, offset_fraction: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    data[int(len(data) * offset_fraction)] ^= 0x10
    path.write_bytes(bytes(data))


@pytest.fixture
def finished(tmp_path):
    config = EvaluationConfig(out=tmp_path / "run", **SMALL)
    return config, run_evaluation(config)


def test_each_part_has_its_checksum(finished):
    config, _ = finished
    parts = sorted((config.out / "parts").glob("*.parquet"))
    assert len(parts) == 4 and all(part_is_intact(p) for p in parts)  # 2 controllers × 2 chunks
    assert all(checksum_path(p).read_text().strip() for p in parts)


def test_a_resume_redoes_a_part_with_one_bit_flipped_and_gives_the_same_rows(finished, capfd):
    config, results = finished
    part = sorted((config.out / "parts").glob("reach__lqr__*.parquet"))[1]
    _flip_one_bit(part)
    assert not part_is_intact(part)
    resumed = run_evaluation(dataclasses.replace(config, resume=True))
    assert f"the part file {part.name} does not match its SHA-256" in capfd.readouterr().err
    assert part.with_name(part.name + ".corrupt").is_file() and part_is_intact(part)
    pd.testing.assert_frame_equal(resumed, results, check_exact=True)


def test_a_part_without_its_checksum_is_redone(finished, capfd):
    config, results = finished
    part = sorted((config.out / "parts").glob("reach__dls__*.parquet"))[0]
    checksum_path(part).unlink()
    resumed = run_evaluation(dataclasses.replace(config, resume=True))
    assert "or has none" in capfd.readouterr().err
    pd.testing.assert_frame_equal(resumed, results, check_exact=True)


def test_a_part_damaged_after_it_was_written_is_refused_when_read(finished):
    config, _ = finished
    part = sorted((config.out / "parts").glob("*.parquet"))[0]
    _flip_one_bit(part, 0.3)
    store = RunStore.__new__(RunStore)  # read_part needs nothing of the run but the file
    with pytest.raises(RunDirectoryError, match=r"changed after it was written \(its SHA-256 does not match"):
        store.read_part(part)
