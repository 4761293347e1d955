"""The pure parts of ``bench.bench_proposal_rn`` on hand-computed cases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.bench_proposal_rn import (
    bar_gaps,
    intervals_overlap,
    label_shift,
    main,
    mean_probs,
    pairwise_gaps,
    run_inputs,
)


def test_bar_gaps_are_the_largest_difference_of_the_mean_probabilities() -> None:
    # dimension 0: means (0.5, 0.5) against (0.8, 0.2) -> 0.3; dimension 1: (0.2, 0.3, 0.5) against itself -> 0
    a = [np.array([[0.9, 0.1], [0.1, 0.9]]), np.array([[0.2, 0.3, 0.5]] * 2)]
    b = [np.array([[0.8, 0.2], [0.8, 0.2]]), np.array([[0.2, 0.3, 0.5]] * 2)]
    assert bar_gaps(a, b) == pytest.approx([0.3, 0.0])


def test_bar_gaps_weigh_the_first_set() -> None:
    # weights 3:1 -> means (0.7, 0.3) against (0.8, 0.2): 0.1
    a = [np.array([[0.9, 0.1], [0.1, 0.9]])]
    b = [np.array([[0.8, 0.2]])]
    assert bar_gaps(a, b, weights_a=[3.0, 1.0]) == pytest.approx([0.1])


def test_bar_gaps_name_a_dimension_mismatch() -> None:
    with pytest.raises(ValueError, match="2 dimensions against 1"):
        bar_gaps([np.ones((1, 2)) / 2] * 2, [np.ones((1, 2)) / 2])


def test_mean_probs_average_each_dimension_over_the_rns() -> None:
    # two RNs, one input: dimension 0 (0.9, 0.1) and (0.5, 0.5) -> (0.7, 0.3); dimension 1 (1, 0, 0) and (0, 0, 1)
    runs = [[np.array([[0.9, 0.1]]), np.array([[1.0, 0.0, 0.0]])], [np.array([[0.5, 0.5]]), np.array([[0.0, 0.0, 1.0]])]]
    got = mean_probs(runs)
    assert np.allclose(got[0], [[0.7, 0.3]]) and np.allclose(got[1], [[0.5, 0.0, 0.5]])


def test_label_shift_scales_each_choice_by_its_weighted_over_raw_share() -> None:
    # plans choose 0, 0, 1 with weights 1, 1, 2: raw shares (2/3, 1/3), weighted (1/2, 1/2) -> factors (3/4, 3/2);
    # (0.5, 0.5) -> (0.375, 0.75) / 1.125 = (1/3, 2/3); a third choice no plan holds keeps its factor 1
    plans = np.array([[0], [0], [1]])
    got = label_shift([np.array([[0.5, 0.5, 0.0], [0.4, 0.2, 0.4]])], plans, np.array([1.0, 1.0, 2.0]))[0]
    assert np.allclose(got[0], [1 / 3, 2 / 3, 0.0])
    # (0.4, 0.2, 0.4) -> (0.3, 0.3, 0.4), already summing to 1
    assert np.allclose(got[1], [0.3, 0.3, 0.4])


def test_intervals_overlap() -> None:
    # 25/50: Wilson 0.366-0.634; 45/50: 0.786-0.957; 35/50: 0.562-0.809
    assert not intervals_overlap((25, 50), (45, 50))
    assert intervals_overlap((35, 50), (45, 50))
    assert intervals_overlap((25, 50), (35, 50))


def test_run_inputs_name_a_missing_run(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="datasets/hammer-seed0 not found"):
        run_inputs(tmp_path, "hammer", 0)


def test_run_inputs_with_a_pointnet_need_no_models(tmp_path: Path) -> None:
    (tmp_path / "datasets" / "unscrew-seed2").mkdir(parents=True)  # a --no-train-rn run: no models/ at all
    pointnet = tmp_path / "pointnet-x.pt"
    assert run_inputs(tmp_path, "unscrew", 2, pointnet) == (tmp_path / "datasets" / "unscrew-seed2",
                                                            "prl/unscrew-seed2", pointnet, None)
    with pytest.raises(FileNotFoundError, match="rn-seed2.pt not found"):
        run_inputs(tmp_path, "unscrew", 2)


def test_a_missing_pointnet_is_refused_before_anything_is_read(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--prior-dir", str(tmp_path / "p"), "--adaptive-dir", str(tmp_path / "a"), "--task", "unscrew",
            "--pointnet", str(tmp_path / "pointnet-missing.pt")]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert f"--pointnet {tmp_path / 'pointnet-missing.pt'}: no such file" in capsys.readouterr().err


def test_a_second_prior_run_of_the_same_seed_is_refused_before_anything_is_read(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the same seed would be the same dataset, not a floor of two; the runs named do not exist, so an error about
    # them would mean the seeds were not checked first
    argv = ["--prior-dir", str(tmp_path / "p"), "--adaptive-dir", str(tmp_path / "a"), "--task", "hammer",
            "--seed", "3", "--second-prior-dir", str(tmp_path / "p2"), "--second-prior-seed", "3"]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "--second-prior-seed must differ from --seed (3)" in capsys.readouterr().err


@pytest.mark.parametrize(("seeds", "message"), [
    (["4", "4"], "--second-prior-seed [4, 4]: each run's seed once"),
    (["4"], "1 --second-prior-seed for 2 --second-prior-dir"),
])
def test_several_other_prior_runs_need_one_seed_each(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     seeds: list[str], message: str) -> None:
    argv = ["--prior-dir", str(tmp_path / "p"), "--adaptive-dir", str(tmp_path / "a"), "--task", "hammer",
            "--second-prior-dir", str(tmp_path / "p2"), "--second-prior-dir", str(tmp_path / "p3")]
    for s in seeds:
        argv += ["--second-prior-seed", s]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_pairwise_gaps_set_each_dataset_against_each_prior_only_one() -> None:
    # one dimension of two choices, one input: the bars are the probabilities themselves
    means = {"p0": [np.array([[1.0, 0.0]])], "p1": [np.array([[0.8, 0.2]])], "p2": [np.array([[0.9, 0.1]])],
             "a": [np.array([[0.5, 0.5]])]}
    priors = {"prior (seed 0)": "p0", "prior (seed 1)": "p1", "prior (seed 2)": "p2"}
    lines = pairwise_gaps(means, priors, "a", 5)
    assert "| mean of 5 RNs | prior (seed 0) | prior (seed 1) | prior (seed 2) |" in lines
    assert "| prior (seed 0) | - | 0.20 | 0.10 |" in lines
    assert "| prior (seed 1) | 0.20 | - | 0.10 |" in lines
    assert "| a | 0.50 | 0.30 | 0.40 |" in lines
    assert lines[-1] == ("Between prior-only datasets: 0.10-0.20 (median 0.10, 3 pairs); a against them: 0.30-0.50 "
                         "(median 0.40).")
    two = pairwise_gaps(means, {"prior (seed 0)": "p0", "prior (seed 1)": "p1"}, "a", 3)
    assert two[-1] == "Between the two prior-only datasets: 0.20; a against them: 0.30-0.50 (median 0.40)."


@pytest.mark.parametrize(("extra", "missing"), [([], "hammer-seed2"), (["--adaptive-seed", "5"], "hammer-seed5")])
def test_the_adaptive_run_is_found_by_its_own_seed(tmp_path: Path, extra: list[str], missing: str) -> None:
    # the prior run is seed 2 and the adaptive run seed 0: without --adaptive-seed the adaptive dataset is looked for
    # under the prior run's seed, with it under its own; either way the one missing is named before anything is read
    (tmp_path / "p" / "datasets" / "hammer-seed2").mkdir(parents=True)
    (tmp_path / "a" / "datasets" / "hammer-seed0").mkdir(parents=True)
    (tmp_path / "pointnet.pt").touch()
    argv = ["--prior-dir", str(tmp_path / "p"), "--adaptive-dir", str(tmp_path / "a"), "--task", "hammer",
            "--seed", "2", "--pointnet", str(tmp_path / "pointnet.pt"), *extra]
    with pytest.raises(FileNotFoundError, match=f"a/datasets/{missing} not found"):
        main(argv)


def test_with_its_seed_the_adaptive_run_is_read_from_its_own_dataset(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # the prior run is seed 2 and the adaptive run seed 0: with --adaptive-seed 0 both are found, and the datasets
    # read are the prior's seed-2 one and then the adaptive's seed-0 one
    import flows.compute_features

    (tmp_path / "p" / "datasets" / "hammer-seed2").mkdir(parents=True)
    (tmp_path / "a" / "datasets" / "hammer-seed0").mkdir(parents=True)
    (tmp_path / "pointnet.pt").touch()
    read: list[tuple[Path, str]] = []

    class Stop(Exception):
        pass

    def fake_rn_features(root: Path, repo: str, *_: object) -> dict:
        read.append((root, repo))
        if len(read) == 2:
            raise Stop
        return {"seeds": np.arange(10)}

    monkeypatch.setattr(flows.compute_features, "rn_features", fake_rn_features)
    argv = ["--prior-dir", str(tmp_path / "p"), "--adaptive-dir", str(tmp_path / "a"), "--task", "hammer",
            "--seed", "2", "--adaptive-seed", "0", "--pointnet", str(tmp_path / "pointnet.pt")]
    with pytest.raises(Stop):
        main(argv)
    assert read == [(tmp_path / "p" / "datasets" / "hammer-seed2", "prl/hammer-seed2"),
                    (tmp_path / "a" / "datasets" / "hammer-seed0", "prl/hammer-seed0")]
