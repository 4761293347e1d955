"""The pure parts of ``bench.bench_cores``: the ceiling by hand, the order of its runs, and its clear errors."""

from __future__ import annotations

import pytest

from bench.bench_cores import ceiling_speedup, main, run_order


def test_the_ceiling_by_hand() -> None:
    # 0.50 s per attempt alone, 0.53 s with two at once: 2 x 0.50 / 0.53 = 1.8868
    assert ceiling_speedup(0.50, 0.53, 2) == pytest.approx(1.8868, abs=1e-4)
    # no slowdown: k processes give k
    assert ceiling_speedup(0.4, 0.4, 3) == pytest.approx(3.0)
    with pytest.raises(ValueError, match="got 0.0 and 0.5"):
        ceiling_speedup(0.0, 0.5, 2)
    with pytest.raises(ValueError, match="processes must be >= 1, got 0"):
        ceiling_speedup(0.5, 0.5, 0)


def test_runs_go_one_k_k_one() -> None:
    assert run_order(2, 2) == [1, 2, 2, 1]
    assert run_order(3, 1) == [1, 3]
    with pytest.raises(ValueError, match="repeats must be 1 or 2, got 3"):
        run_order(2, 3)


def test_bad_settings_are_clear_errors(capsys: pytest.CaptureFixture[str]) -> None:
    for argv, message in ((["--task", "hamer"], "unknown task(s) ['hamer']"),
                          (["--attempts", "0"], "--attempts must be > 0, got 0"),
                          (["--processes", "1"], "--processes must be >= 2, got 1"),
                          (["--pin", "--dask"], "--pin pins bare processes; it does not go with --dask")):
        with pytest.raises(SystemExit):
            main(argv)
        assert message in capsys.readouterr().err
