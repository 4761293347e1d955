"""python -m flows.critic: the attempts it reads, its feature cache, and its errors (the training and the runs in
simulation are tests/prl/test_critic.py and tests/envs/test_attempt_features.py)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from flows.critic import attempts_of, cached_features, main


def write_shard(root, task, shard, rows):
    d = root / task / f"shard{shard:03d}"
    d.mkdir(parents=True)
    (d / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_attempts_are_read_shard_by_shard_without_the_ones_that_raised(tmp_path):
    write_shard(tmp_path, "sweep", 1, [{"attempt": 0, "seed": 30, "plan": [0, 1, 2, 0, 0, 0], "success": True}])
    write_shard(tmp_path, "sweep", 0, [
        {"attempt": 0, "seed": 10, "plan": [1, 1, 1, 1, 1, 1], "success": False},
        {"attempt": 1, "seed": 11, "plan": [2, 2, 2, 2, 2, 2], "success": False, "error": "PhysX: boom"},
        {"attempt": 2, "seed": 12, "plan": [3, 3, 3, 3, 3, 3], "success": True}])
    seeds, plans, success = attempts_of(tmp_path, "sweep")
    assert seeds.tolist() == [10, 12, 30]
    assert plans[:, 0].tolist() == [1, 3, 0] and success.tolist() == [False, True, True]
    with pytest.raises(FileNotFoundError, match="no attempts of task 'hammer'"):
        attempts_of(tmp_path, "hammer")


def test_cached_features_are_reused_only_for_the_same_seeds_and_pointnet(tmp_path):
    from prl.version import file_digest, outcome_version

    pn = tmp_path / "pn.pt"
    pn.write_bytes(b"weights")
    seeds = np.array([4, 5], dtype=np.int64)
    key = hashlib.sha256(f"sweep/{outcome_version('sweep')}/{file_digest(pn)}/64/".encode() + seeds.tobytes()).hexdigest()
    path = tmp_path / "x.npz"
    np.savez(path, x=np.full((2, 3), 7.0, np.float32), key=np.array(key))
    np.testing.assert_array_equal(cached_features(path, "sweep", seeds, pn, 64), np.full((2, 3), 7.0))


def test_cli_errors_name_the_bad_value(tmp_path, capsys):
    assert main(["--synthesis-dir", str(tmp_path), "--task", "sweep", "--rn-path", str(tmp_path / "rn.pt")]) == 2
    assert "rn.pt" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--synthesis-dir", str(tmp_path), "--task", "sweep", "--rn-path", "x", "--kinds", "rn,best"])
    assert "'best'" in capsys.readouterr().err
