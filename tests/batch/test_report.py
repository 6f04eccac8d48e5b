"""The report's tables, from a hand-made score table (no batch run)."""

from __future__ import annotations

from pathlib import Path

from ippc.batch.report import write_report
from ippc.batch.results import RoundRecord
from ippc.batch.scoring import score


def test_domain_rows_show_an_interval_only_where_there_is_one(tmp_path: Path) -> None:
    records = [
        RoundRecord(planner, instance, instance.split("__")[0], reward)
        for instance, rewards in (("a__1", (0, 1, 4)), ("a__2", (0, 1, 2)), ("b__1", (0, 2, 3)))
        for planner, reward in zip(("noop", "random", "p"), rewards, strict=True)
    ]
    table = score(records, "ippc2011", expected_rounds=1)
    text = write_report(table, records, [], tmp_path).read_text()
    # domain a: p scores 1 on both instances (interval 0); domain b: one instance, no interval
    assert "| a | 0.000 ± 0.00 | 0.000 ± 0.00 | 1.000 ± 0.00 |" in text
    assert "| b | 0.000 | 0.000 | 1.000 |" in text
