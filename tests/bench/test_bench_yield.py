"""The pure parts of ``bench.bench_yield``: its table on a hand-made record, and its clear errors."""

from __future__ import annotations

import pytest

from bench.bench_yield import main, table


def test_the_table_by_hand() -> None:
    # 40 of 100 attempts kept: yield 0.40, Wilson (0.31-0.50); entropy mean of (1.0, 0.5) = 0.75
    rec = {"kept": 40, "attempts": 100, "rounds": [{"distinct_plans": 7, "ess": 12.4}], "entropy_all": [1.0, 0.5],
           "frames_per_attempt": 701.2}
    rows = table([("prior", {"tweeze": rec})]).splitlines()
    assert rows[2] == "| tweeze | prior | 100 | 40 | 0.40 (0.31-0.50) | 7 | 0.75 | 12 | 701 |"


def test_bad_settings_are_clear_errors(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    assert main(["--replay", "1.5", "--output-dir", str(tmp_path)]) == 2
    assert "replay share must be a number in [0, 1], got 1.5" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--replay", "half"])
    assert "expected numbers separated by commas, got 'half'" in capsys.readouterr().err
