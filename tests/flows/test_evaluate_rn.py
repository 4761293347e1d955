"""flows.evaluate_rn: its argument checks and how it finds the RN's PointNet (the simulated run itself is
checked against the pipeline's own rn-eval in test_full_pipeline)."""

from __future__ import annotations

from pathlib import Path

import pytest

from flows.evaluate_rn import check_eval_args, find_pointnet, main
from prl.features import FEATURE_LAYOUT
from prl.rn import RepresentationNetwork, RNConfig
from prl.rn_checkpoint import save_rn
from prl.version import file_digest


@pytest.mark.parametrize(("args", "match"), [
    (("hamer", 5, 0, 1.0, ("rn",)), "unknown task 'hamer'"),
    (("hammer", 5, 0, 1.0, ("rn", "greedy")), "unknown RN decoding 'greedy'; known: rn, rn_library, rn_success"),
    (("hammer", 5, 0, 1.0, ("rn", "prior")),
     r"unknown RN decoding 'prior'; known: rn, rn_library, rn_success \('prior' and 'expert' are baselines, always run\)"),
    (("hammer", 0, 0, 1.0, ("rn",)), "scenes must be >= 1, got 0"),
    (("hammer", 5, -3, 1.0, ("rn",)), "first_seed must be >= 0, got -3"),
    (("hammer", 5, 0, 0.5, ("rn",)), "randomization must be a scale >= 1, got 0.5"),
])
def test_bad_arguments_are_named(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        check_eval_args(*args)


def _rn(tmp_path: Path, pointnet_sha256: str | None) -> Path:
    model = RepresentationNetwork(FEATURE_LAYOUT.dim)
    model.pointnet_sha256 = pointnet_sha256
    return save_rn(model, RNConfig(epochs=1), FEATURE_LAYOUT, tmp_path / "models" / "rn-seed0.pt")


def test_pointnet_is_found_beside_the_rn_by_digest(tmp_path: Path) -> None:
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "pointnet-aaa.pt").write_bytes(b"one")
    (tmp_path / "models" / "pointnet-bbb.pt").write_bytes(b"two")
    rn = _rn(tmp_path, file_digest(tmp_path / "models" / "pointnet-bbb.pt"))
    assert find_pointnet(rn, None) == tmp_path / "models" / "pointnet-bbb.pt"
    assert find_pointnet(rn, tmp_path / "models" / "pointnet-bbb.pt") == tmp_path / "models" / "pointnet-bbb.pt"
    with pytest.raises(ValueError, match=r"pointnet-aaa.pt \(sha256 [0-9a-f]{12}\) is not the one this RN"):
        find_pointnet(rn, tmp_path / "models" / "pointnet-aaa.pt")
    (tmp_path / "models" / "pointnet-bbb.pt").write_bytes(b"retrained")
    with pytest.raises(FileNotFoundError, match=r"no pointnet-\*.pt beside .*rn-seed0.pt has the sha256"):
        find_pointnet(rn, None)


def test_an_rn_without_a_recorded_pointnet_needs_one_given(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rn = _rn(tmp_path, None)
    with pytest.raises(ValueError, match="does not record its PointNet; pass --pointnet-path"):
        find_pointnet(rn, None)
    # the CLI fails with the message and exit status 2 before any flow or MLflow run starts
    assert main(["--rn-path", str(rn)]) == 2
    assert "does not record its PointNet" in capsys.readouterr().err
    assert main(["--rn-path", str(tmp_path / "none.pt")]) == 2
    assert "RN checkpoint not found" in capsys.readouterr().err
