"""PointNet encoder PN (prl.pointnet): architecture, synthetic data, a short training run, checkpoints."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from prl import pointnet as P
from prl.shapes import hammer_object_mesh, hammer_tool_mesh, sample_points

#: Small enough to train in a few seconds on one CPU thread, big enough to learn the categories.
SMALL = {"n_points": 128, "n_shapes": 320, "n_val": 160, "epochs": 5, "channels": (32, 64, 128), "lr": 3e-3, "seed": 0}
#: Tiny: for determinism and plumbing tests.
TINY = {"n_points": 64, "n_shapes": 48, "n_val": 16, "epochs": 1, "channels": (16, 32), "head": (256,), "seed": 5}

HAMMER = {"handle_radius": 0.016, "handle_half_length": 0.1, "head_radius": 0.02, "head_half_length": 0.04}


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def trained():
    torch.set_num_threads(1)
    cfg = P.pointnet_config("quick", **SMALL)
    seen = []
    model, history = P.train_pointnet(cfg, on_epoch=lambda epoch, metrics: seen.append((epoch, metrics)))
    return cfg, model, history, seen


def test_config_validation_names_bad_value():
    with pytest.raises(ValueError, match="-3"):
        P.PointNetConfig(epochs=-3)
    with pytest.raises(ValueError, match="feature_dim 128"):
        P.PointNetConfig(feature_dim=128)
    with pytest.raises(ValueError, match="teapot"):
        P.PointNetConfig(categories=("box", "teapot"))
    with pytest.raises(ValueError, match="'huge'"):
        P.pointnet_config("huge")
    assert P.pointnet_config("paper").n_shapes > P.pointnet_config("quick").n_shapes


def test_encoder_shapes_and_feature_is_the_layer_before_the_heads():
    cfg = P.PointNetConfig(**TINY)
    model = P.PointNetEncoder(cfg).eval()
    x = torch.randn(5, 64, 3) * 0.05
    logits, size = model(x)
    assert logits.shape == (5, len(cfg.categories)) and size.shape == (5, 3)
    feat = model.features(x)
    assert feat.shape == (5, P.PN_DIM)
    torch.testing.assert_close(model.category_head(feat), logits)
    torch.testing.assert_close(model.size_head(feat), size)
    with pytest.raises(ValueError, match=r"\(5, 64\)"):
        model.features(x[..., 0])


def test_shape_dataset_balanced_deterministic_and_unscaled():
    cfg = P.PointNetConfig(**TINY)
    n = 4 * len(cfg.categories)
    pts, cat, ext = P.make_shape_dataset(cfg, seed=11, n=n)
    assert pts.shape == (n, 64, 3) and pts.dtype == np.float32
    assert cat.dtype == np.int64 and ext.shape == (n, 3)
    assert np.bincount(cat, minlength=len(cfg.categories)).tolist() == [4] * len(cfg.categories)
    again = P.make_shape_dataset(cfg, seed=11, n=n)
    np.testing.assert_array_equal(pts, again[0])
    np.testing.assert_array_equal(cat, again[1])
    assert not np.array_equal(pts, P.make_shape_dataset(cfg, seed=12, n=n)[0])
    # the clouds keep their size: their spread follows the bounding-box extents
    spread = pts.max(axis=1) - pts.min(axis=1)
    np.testing.assert_allclose(spread, ext, rtol=0.35, atol=1e-3)
    assert ext.max() / ext.max(axis=1).min() > 5, "sizes should span orders of magnitude"


def test_training_is_deterministic_for_a_seed():
    cfg = P.PointNetConfig(**TINY)
    model_a, hist_a = P.train_pointnet(cfg)
    model_b, hist_b = P.train_pointnet(cfg)
    assert {k: v for k, v in hist_a.items() if k != "elapsed_s"} == {
        k: v for k, v in hist_b.items() if k != "elapsed_s"
    }
    for (name, a), b in zip(model_a.state_dict().items(), model_b.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0, msg=name)


@pytest.mark.train
def test_short_training_beats_chance_on_held_out_shapes(trained):
    cfg, _, history, seen = trained
    chance = 1.0 / len(cfg.categories)
    assert history["val_acc"][-1] > chance + 0.2, history["val_acc"]
    assert history["val_size_err_pct"][-1] < 60.0, history["val_size_err_pct"]
    assert history["loss"][-1] < history["loss"][0]
    assert [epoch for epoch, _ in seen] == list(range(cfg.epochs))
    assert all(len(values) == cfg.epochs for values in history.values())


@pytest.mark.train
def test_encode_points_and_save_load_round_trip(trained, tmp_path):
    cfg, model, _, _ = trained
    clouds = np.stack([sample_points(hammer_tool_mesh(HAMMER), cfg.n_points, seed=s) for s in range(3)]
                      + [sample_points(hammer_object_mesh({}), cfg.n_points, seed=0)])
    feats = P.encode_points(model, clouds, batch_size=3)
    assert feats.shape == (4, P.PN_DIM) and feats.dtype == np.float32
    np.testing.assert_allclose(P.encode_points(model, clouds[0])[0], feats[0], atol=1e-5)  # batch-size noise
    # features depend on the shape: hammer clouds are closer to each other than to the nail
    assert np.linalg.norm(feats[0] - feats[1]) < np.linalg.norm(feats[0] - feats[3])

    path = P.save_pointnet(model, cfg, tmp_path / "pn" / "pointnet.pt")
    loaded = P.load_pointnet(path)
    assert loaded.cfg == cfg and not loaded.training
    np.testing.assert_array_equal(P.encode_points(loaded, clouds, batch_size=3), feats)


def test_load_errors_name_the_problem(tmp_path):
    missing = tmp_path / "nowhere.pt"
    with pytest.raises(FileNotFoundError, match="nowhere.pt"):
        P.load_pointnet(missing)
    cfg = dataclasses.replace(P.PointNetConfig(**TINY), head=(64,), feature_dim=64)
    path = P.save_pointnet(P.PointNetEncoder(cfg), cfg, tmp_path / "small.pt")
    with pytest.raises(ValueError, match="feature_dim 64"):
        P.load_pointnet(path)
    assert P.load_pointnet(path, feature_dim=64).cfg.feature_dim == 64
    torch.save({"format": 99}, tmp_path / "future.pt")
    with pytest.raises(ValueError, match="99"):
        P.load_pointnet(tmp_path / "future.pt")


def test_encode_points_rejects_bad_shapes():
    model = P.PointNetEncoder(P.PointNetConfig(**TINY))
    with pytest.raises(ValueError, match=r"\(2, 5\)"):
        P.encode_points(model, np.zeros((2, 5)))
    with pytest.raises(ValueError, match="NaN"):
        P.encode_points(model, np.full((1, 8, 3), np.nan))
