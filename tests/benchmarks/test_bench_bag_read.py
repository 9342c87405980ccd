"""The bag-read benchmark: one row per kind of bag, growth as the ratio of its own figures."""

import json
from pathlib import Path

import pytest

from benchmarks.bench_bag_read import KINDS, LONGER, main


def test_every_kind_of_bag_is_timed_at_both_lengths(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--pairs", "12", "--runs", "1", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "bag_read.json").read_text())
    assert (result["pairs"], result["longer"], result["runs"]) == (12, LONGER, 1)
    assert [row["kind"] for row in result["rows"]] == list(KINDS)
    for row in result["rows"]:
        for way in ("cursor", "query_per_frame"):
            short, long = row[f"{way}_short_ms_per_pair"], row[f"{way}_long_ms_per_pair"]
            assert short > 0 and long > 0
            # one round: the median growth is that round's long over short
            assert row[f"{way}_growth"] == pytest.approx(long / short)
    table = (tmp_path / "bag_read.md").read_text()
    assert table == capsys.readouterr().out
    rows = table.splitlines()[4 : 4 + len(KINDS)]
    assert [line.split(" | ")[0] for line in rows] == [f"| {kind}" for kind in KINDS]
