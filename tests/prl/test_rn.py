"""Representation Network: Eq 3 terms against hand-computed values, Table I, training, checkpoints, Fig 7."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from prl.constants import RS_DIMS
from prl.rn import FeatureLayout, RepresentationNetwork, RNConfig, check_features, rn_loss, split_logits
from prl.rn_checkpoint import load_rn, save_rn
from prl.rn_decode import (
    key_dimensions,
    library_plan,
    per_dim_accuracy,
    plan_libraries,
    plan_library,
    predict_plan,
    predict_proba,
)
from prl.rn_train import batch_indices, train_rn

DIMS = (2, 4)
#: The project's input layout (prl.features.FEATURE_LAYOUT has the same lengths).
LAYOUT = FeatureLayout((("x_manip", 784), ("te", 384), ("pn_tool", 256), ("pn_object", 256)))


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _logits_of(*probs: list[float]) -> torch.Tensor:
    """Logits whose softmax is ``probs`` (one row per sample)."""
    return torch.log(torch.tensor(probs, dtype=torch.float64))


def _cfg(**kw: object) -> RNConfig:
    return RNConfig(**{"batch_size": 2, "dims": DIMS, **kw})


# ------------------------------------------------------------------ config


def test_paper_defaults_resolve_from_batch_size() -> None:
    cfg = RNConfig()
    assert (cfg.batch_size, cfg.epochs, cfg.tau_c, cfg.tau_s, cfg.dims) == (64, 200, 2.0, 2.0, RS_DIMS)
    assert cfg.lam_value == 64.0 and cfg.gamma_value == pytest.approx(0.64) and cfg.t_min_value == 6.4
    cfg = RNConfig(batch_size=32, lam=5.0, gamma=0.0, t_min=1)
    assert (cfg.lam_value, cfg.gamma_value, cfg.t_min_value) == (5.0, 0.0, 1.0)
    assert RNConfig(batch_size=10).params()["gamma"] == pytest.approx(0.1)


@pytest.mark.parametrize(("field", "value"), [
    ("batch_size", 1), ("lam", -1.0), ("gamma", float("nan")), ("tau_c", 0.0), ("tau_s", -2.0),
    ("t_min", -0.5), ("epochs", 0), ("lr", 0.0), ("weight_decay", -1e-4), ("seed", -3), ("dims", (7, 1)),
])
def test_config_rejects_bad_values_naming_them(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field) as err:
        RNConfig(**{field: value})
    assert str(value) in str(err.value)


# ------------------------------------------------------------------ Eq 3, term by term


def test_ce_is_summed_over_batch_and_dimensions() -> None:
    d0 = torch.tensor([[1.0, -0.5], [0.2, 0.3]], dtype=torch.float64)
    d1 = torch.tensor([[0.0, 1.0, 2.0, -1.0], [0.5, 0.5, -2.0, 3.0]], dtype=torch.float64)
    y = torch.tensor([[0, 2], [1, 0]])

    def nll(row: list[float], k: int) -> float:
        return -(row[k] - math.log(sum(math.exp(v) for v in row)))

    expected = (nll([1.0, -0.5], 0) + nll([0.2, 0.3], 1)) + (nll([0.0, 1.0, 2.0, -1.0], 2)
                                                             + nll([0.5, 0.5, -2.0, 3.0], 0))
    terms = rn_loss([d0, d1], y, _cfg())
    assert float(terms["ce"]) == pytest.approx(expected, rel=1e-12)


def test_confidence_hinge_uniform_logits() -> None:
    """Uniform logits: p_max = 1/m, hinge 2/m - 1/m = 1/m per dimension: 1/2 + 1/4, times lambda."""
    terms = rn_loss([torch.zeros(2, 2), torch.zeros(2, 4)], torch.zeros(2, 2, dtype=torch.long), _cfg(lam=3.0))
    assert float(terms["confidence"]) == pytest.approx(3.0 * (1 / 2 + 1 / 4), rel=1e-6)
    # the paper's lambda = 1 x bs
    terms = rn_loss([torch.zeros(2, 2), torch.zeros(2, 4)], torch.zeros(2, 2, dtype=torch.long), _cfg())
    assert float(terms["confidence"]) == pytest.approx(2.0 * 0.75, rel=1e-6)


def test_confidence_hinge_is_batch_mean_of_known_probabilities() -> None:
    # sample 0 uniform; sample 1: dim0 p_max 0.6 < 2/2 -> hinge 0.4; dim1 p_max 0.7 > 2/4 -> hinge 0
    d0 = _logits_of([0.5, 0.5], [0.6, 0.4])
    d1 = _logits_of([0.25] * 4, [0.7, 0.1, 0.1, 0.1])
    terms = rn_loss([d0, d1], torch.zeros(2, 2, dtype=torch.long), _cfg(lam=1.0))
    expected = (0.5 + 0.4) / 2 + (0.25 + 0.0) / 2
    assert float(terms["confidence"]) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(("t_min", "on"), [(1.0, 0.0), (2.0, 0.0), (2.01, 1.0), (3.0, 1.0)])
def test_count_indicator_at_the_t_min_boundary(t_min: float, on: float) -> None:
    """tau_s = 1: thresholds 1/2 and 1/4 (strict). Confident pairs: sample 0 both dims (0.6, 0.7);
    sample 1 none (uniform probabilities equal the thresholds exactly). C = 2; fires iff 2 < T_min."""
    d0 = _logits_of([0.6, 0.4], [0.5, 0.5])
    d1 = _logits_of([0.7, 0.1, 0.1, 0.1], [0.25] * 4)
    terms = rn_loss([d0, d1], torch.zeros(2, 2, dtype=torch.long), _cfg(tau_s=1.0, gamma=0.7, t_min=t_min))
    assert float(terms["n_confident"]) == 2.0
    assert float(terms["count_on"]) == on
    assert float(terms["count"]) == pytest.approx(0.7 * on)
    total = float(terms["ce"]) + float(terms["confidence"]) + float(terms["count"])
    assert float(terms["total"]) == pytest.approx(total, rel=1e-12)


def test_count_with_paper_thresholds() -> None:
    """tau_s = 2 on RS_DIMS: thresholds 2/m; with T_min = 6.4 the batch needs >= 7 confident pairs."""
    cfg = RNConfig(batch_size=4)  # T_min = 0.4: one confident pair is enough
    logits = [torch.zeros(4, m) for m in RS_DIMS]
    logits[3] = _logits_of(*[[0.55, 0.15, 0.15, 0.15]] * 4).float()  # 0.55 > 2/4 in all 4 samples
    y = torch.zeros(4, len(RS_DIMS), dtype=torch.long)
    terms = rn_loss(logits, y, cfg)
    assert float(terms["n_confident"]) == 4.0 and float(terms["count_on"]) == 0.0
    terms = rn_loss(logits, y, RNConfig(batch_size=4, t_min=6.4))
    assert float(terms["count_on"]) == 1.0 and float(terms["count"]) == pytest.approx(0.04)


def test_indicator_carries_no_gradient() -> None:
    d0 = torch.tensor([[0.3, -0.2], [1.0, 0.1]], dtype=torch.float64, requires_grad=True)
    d1 = torch.tensor([[0.1, 0.2, 0.0, -0.3], [0.4, -1.0, 0.2, 0.0]], dtype=torch.float64, requires_grad=True)
    y = torch.tensor([[1, 3], [0, 0]])
    cfg = _cfg(gamma=5.0, t_min=100.0)
    terms = rn_loss([d0, d1], y, cfg)
    assert float(terms["count"]) == 5.0 and not terms["count"].requires_grad
    g_total = torch.autograd.grad(terms["total"], [d0, d1])
    terms = rn_loss([d0, d1], y, cfg)
    g_parts = torch.autograd.grad(terms["ce"] + terms["confidence"], [d0, d1])
    for a, b in zip(g_total, g_parts, strict=True):
        assert torch.equal(a, b)
    assert any(float(g.abs().sum()) > 0 for g in g_total)


def test_loss_rejects_mismatched_inputs() -> None:
    with pytest.raises(ValueError, match=r"\(2, 4\)"):
        rn_loss([torch.zeros(2, 2), torch.zeros(2, 3)], torch.zeros(2, 2, dtype=torch.long), _cfg())
    with pytest.raises(ValueError, match="a1 is 4"):
        rn_loss([torch.zeros(2, 2), torch.zeros(2, 4)], torch.tensor([[0, 0], [1, 4]]), _cfg())


# ------------------------------------------------------------------ Table I


def test_architecture_is_table_one() -> None:
    net = RepresentationNetwork(1680)
    assert net.in_dim == 1680 and net.dims == RS_DIMS
    layers = list(net.layers)
    kinds = [type(m) for m in layers]
    block = [nn.Linear, nn.BatchNorm1d, nn.ReLU, nn.Dropout]
    assert kinds == block * 3 + [nn.Linear]
    linears = [m for m in layers if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(1680, 512), (512, 256), (256, 128), (128, 37)]
    assert [m.num_features for m in layers if isinstance(m, nn.BatchNorm1d)] == [512, 256, 128]
    assert [m.p for m in layers if isinstance(m, nn.Dropout)] == [0.5, 0.5, 0.4]
    net.eval()
    logits = net(torch.zeros(3, 1680))
    assert logits.shape == (3, 37)
    assert [p.shape[1] for p in split_logits(logits, RS_DIMS)] == list(RS_DIMS)
    assert RepresentationNetwork(11, (3, 5)).layers[0].in_features == 11
    with pytest.raises(ValueError, match="1680"):
        net(torch.zeros(2, 1679))


# ------------------------------------------------------------------ training


def _synthetic(n: int, seed: int, dims: tuple[int, ...] = RS_DIMS, noise: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Labels a deterministic function of x: x holds one block of m_i features per dimension, a
    one-hot code of a random choice plus jitter below 0.5, so the label is the argmax of the block;
    ``noise`` extra features carry nothing. Features are offset and scaled (standardisation)."""
    rng = np.random.default_rng(seed)
    labels = np.stack([rng.integers(0, m, n) for m in dims], axis=1)
    code = np.concatenate([np.eye(m)[labels[:, i]] for i, m in enumerate(dims)], axis=1)
    x = np.concatenate([code + rng.uniform(-0.3, 0.3, size=code.shape), rng.normal(size=(n, noise))], axis=1)
    starts = np.cumsum((0,) + dims[:-1])
    y = np.stack([x[:, s : s + m].argmax(axis=1) for s, m in zip(starts, dims, strict=True)], axis=1)
    assert np.array_equal(y, labels)
    return (5.0 + 3.0 * x).astype(np.float32), y.astype(np.int64)


@pytest.mark.train
def test_training_learns_a_separable_problem() -> None:
    """The paper's config (lambda = 1 x bs, gamma = 0.01 x bs, tau 2, T_min bs/10): all three Eq 3 terms active."""
    x, y = _synthetic(1000, seed=0, noise=8)
    xv, yv = _synthetic(300, seed=1, noise=8)
    seen = []
    model, history = train_rn(x, y, RNConfig(epochs=20), xv, yv, on_epoch=lambda e, r: seen.append(e),
                              progress=False)
    assert seen == list(range(20)) and len(history) == 20
    acc = per_dim_accuracy(model, xv, yv)
    assert acc.shape == (6,) and acc.min() > 0.9, acc
    assert history[-1]["rn/val_acc_mean"] == pytest.approx(acc.mean(), abs=1e-6)
    assert history[-1]["rn/loss_total"] < history[0]["rn/loss_total"]
    for key in ("rn/loss_ce", "rn/loss_conf", "rn/loss_count", "rn/train_acc_a5", "rn/val_loss_ce"):
        assert key in history[0]
    probs = predict_proba(model, xv)
    assert [p.shape for p in probs] == [(300, m) for m in RS_DIMS]
    assert np.allclose([p.sum(axis=1) for p in probs], 1.0, atol=1e-5)


def test_training_is_deterministic_and_leaves_global_rng_alone() -> None:
    x, y = _synthetic(150, seed=2)
    cfg = RNConfig(epochs=2, batch_size=32, seed=7)
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    m1, h1 = train_rn(x, y, cfg, progress=False)
    assert torch.equal(torch.rand(1), before)
    m2, h2 = train_rn(x, y, cfg, progress=False)
    p1, p2 = predict_proba(m1, x), predict_proba(m2, x)
    assert all(np.array_equal(a, b) for a, b in zip(p1, p2, strict=True))
    assert [r["rn/loss_total"] for r in h1] == [r["rn/loss_total"] for r in h2]
    m3, _ = train_rn(x, y, RNConfig(epochs=2, batch_size=32, seed=8), progress=False)
    assert not np.array_equal(predict_proba(m3, x)[0], p1[0])


def test_batches_drop_last_and_tiny_sets() -> None:
    rng = np.random.default_rng(0)
    batches = batch_indices(150, 64, rng)
    assert [len(b) for b in batches] == [64, 64] and len(set(np.concatenate(batches))) == 128
    assert [len(b) for b in batch_indices(64, 64, rng)] == [64]
    assert sorted(batch_indices(5, 64, rng)[0]) == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="at least 2 samples"):
        batch_indices(1, 64, rng)
    x, y = _synthetic(5, seed=0)  # smaller than a batch: one batch of 5 per epoch
    model, history = train_rn(x, y, RNConfig(epochs=2), progress=False)
    assert len(history) == 2 and predict_plan(model, x).shape == (5, 6)


def test_standardisation_is_stored_in_the_model() -> None:
    x, y = _synthetic(100, seed=3)
    x[:, -1] = 4.0  # a constant feature: centred, not divided by 0
    model, _ = train_rn(x, y, RNConfig(epochs=1), progress=False)
    assert np.allclose(model.x_mean.numpy(), x.mean(axis=0), atol=1e-4)
    assert np.allclose(model.x_std.numpy()[:-1], x.std(axis=0)[:-1], rtol=1e-4) and model.x_std[-1] == 1.0


@pytest.mark.parametrize(("mutate", "match"), [
    (lambda x, y: (x, np.where(np.arange(len(y))[:, None] == 3, [7, 0, 0, 0, 0, 0], y)), r"a0 has 7 choices.*value 7 at row 3"),
    (lambda x, y: (x, np.where(np.arange(len(y))[:, None] == 0, [0, 0, 0, -1, 0, 0], y)), r"a3 .* value -1 .*no label"),
    (lambda x, y: (x, y[:-1]), "10 samples but y_train has 9"),
    (lambda x, y: (x[:0], y[:0]), "x_train is empty"),
    (lambda x, y: (np.where(np.arange(x.size).reshape(x.shape) == 5, np.nan, x), y), r"non-finite.*row 0, feature 5"),
    (lambda x, y: (x, y.astype(float)), "integer class indices"),
    (lambda x, y: (x, y[:, :5]), r"shape \(samples, 6\)"),
])
def test_bad_training_data_raise_naming_the_value(mutate: object, match: str) -> None:
    x, y = _synthetic(10, seed=0)
    bad_x, bad_y = mutate(x, y)  # type: ignore[operator]
    with pytest.raises(ValueError, match=match):
        train_rn(bad_x, bad_y, RNConfig(epochs=1), progress=False)


# ------------------------------------------------------------------ layout and checkpoints


def test_feature_layout() -> None:
    assert LAYOUT.dim == 1680
    assert [n for n, _ in LAYOUT.segments] == ["x_manip", "te", "pn_tool", "pn_object"]
    assert LAYOUT.slice("pn_tool") == slice(1168, 1424)
    assert FeatureLayout.from_json(LAYOUT.to_json()) == LAYOUT
    with pytest.raises(ValueError, match="'te'"):
        FeatureLayout((("te", 0),))
    with pytest.raises(ValueError, match="duplicate"):
        FeatureLayout((("a", 1), ("a", 2)))
    with pytest.raises(ValueError, match="length 1679, but the layout expects 1680"):
        check_features(np.zeros((2, 1679)), LAYOUT)
    with pytest.raises(ValueError, match="length 1681, but the layout expects 1680"):
        LAYOUT.check(np.zeros((2, 1681)))
    with pytest.raises(ValueError, match="non-finite.*row 1, feature 0"):
        LAYOUT.check(np.where(np.arange(2)[:, None] == 1, np.nan, np.zeros((2, 1680))))
    assert check_features(np.zeros(1680), LAYOUT).shape == (1, 1680)


def test_save_load_round_trip_and_layout_mismatch(tmp_path: Path) -> None:
    dims = (3, 4)
    layout = FeatureLayout((("a", 6), ("b", 4)))
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 10)).astype(np.float32)
    y = np.stack([x[:, :3].argmax(1), x[:, 3:7].argmax(1)], axis=1)
    cfg = RNConfig(epochs=2, batch_size=16, dims=dims, seed=4)
    model, _ = train_rn(x, y, cfg, progress=False)
    path = save_rn(model, cfg, layout, tmp_path / "rn" / "model.pt")
    assert model.config == cfg and model.layout is None
    loaded = load_rn(path, expected_layout=layout)
    assert loaded.config == cfg and loaded.layout == layout and not loaded.training
    for a, b in zip(predict_proba(model, x), predict_proba(loaded, x), strict=True):
        assert np.array_equal(a, b)
    assert np.array_equal(predict_plan(model, x), predict_plan(loaded, x))
    assert loaded.plan_libraries == {}
    model.plan_libraries = plan_libraries(y[:6], ["a", "b"] * 3)
    again = load_rn(save_rn(model, cfg, layout, tmp_path / "lib.pt"))
    assert sorted(again.plan_libraries) == ["a", "b"]
    assert np.array_equal(again.plan_libraries["b"], plan_library(y[1:6:2]))
    assert np.array_equal(predict_plan(again, x, again.plan_libraries["a"]),
                          predict_plan(model, x, model.plan_libraries["a"]))
    # the sampling prior and the PointNet digest travel with the model
    model.plan_priors = {"a": (np.array([0.5, 0.25, 0.25]), np.full(4, 0.25))}
    model.pointnet_sha256 = "ab" * 32
    again = load_rn(save_rn(model, cfg, layout, tmp_path / "prior.pt"))
    assert [q.tolist() for q in again.plan_priors["a"]] == [[0.5, 0.25, 0.25], [0.25] * 4]
    assert again.pointnet_sha256 == "ab" * 32 and loaded.plan_priors == {} and loaded.pointnet_sha256 is None
    model.plan_priors = {"a": (np.array([0.5, 0.5, 0.5]), np.full(4, 0.25))}
    with pytest.raises(ValueError, match=r"plan prior of task 'a' dimension 0 must be positive probabilities"):
        save_rn(model, cfg, layout, tmp_path / "badprior.pt")
    model.plan_priors = {}
    model.plan_libraries = {"a": np.array([[0, 4]])}  # dimension 1 has 4 choices
    with pytest.raises(ValueError, match=r"plan library of task 'a' row 0 has choice 4 for dimension 1, which has 4 choices"):
        save_rn(model, cfg, layout, tmp_path / "badlib.pt")
    other = FeatureLayout((("a", 5), ("b", 5)))
    with pytest.raises(ValueError, match=r"a 6 \| b 4 = 10.*a 5 \| b 5 = 10"):
        load_rn(path, expected_layout=other)
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_rn(tmp_path / "nope.pt")
    with pytest.raises(ValueError, match="does not match the model's input length 10"):
        save_rn(model, cfg, LAYOUT, tmp_path / "bad.pt")
    (tmp_path / "junk.pt").write_text("not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt"):
        load_rn(tmp_path / "junk.pt")


# ------------------------------------------------------------------ decoding over a plan library


def test_library_plan_hand_computed() -> None:
    # sample 0: p0 = (.5, .3, .2), p1 = (.4, .6) -> per-dimension argmax (0, 1)
    # sample 1: p0 = (.1, .1, .8), p1 = (.9, .1) -> per-dimension argmax (2, 0)
    probs = [np.array([[0.5, 0.3, 0.2], [0.1, 0.1, 0.8]]), np.array([[0.4, 0.6], [0.9, 0.1]])]
    library = np.array([[0, 0], [1, 1], [2, 1]])
    # sample 0 scores: .5*.4 = .20, .3*.6 = .18, .2*.6 = .12 -> (0, 0)
    # sample 1 scores: .1*.9 = .09, .1*.1 = .01, .8*.1 = .08 -> (0, 0)
    assert library_plan(probs, library).tolist() == [[0, 0], [0, 0]]
    # (1, 1) beats (2, 1) for sample 1 only when (0, 0) is gone: .01 < .08 -> (2, 1)
    assert library_plan(probs, library[1:]).tolist() == [[1, 1], [2, 1]]
    # the full grid as library gives back the per-dimension argmax
    grid = np.array([[a, b] for a in range(3) for b in range(2)])
    assert library_plan(probs, grid).tolist() == [[0, 1], [2, 0]]
    # prior correction: divide by prior (.5,.25,.25) x (.8,.2): sample 0 .2/.4 = .5, .18/.05 = 3.6, .12/.05 = 2.4
    prior = [np.array([0.5, 0.25, 0.25]), np.array([0.8, 0.2])]
    assert library_plan(probs, library, prior).tolist()[0] == [1, 1]
    # sample 1: .09/.4 = .225, .01/.05 = .2, .08/.05 = 1.6 -> (2, 1)
    assert library_plan(probs, library, prior).tolist()[1] == [2, 1]
    with pytest.raises(ValueError, match=r"prior dimension 0 must be positive probabilities summing to 1, "
                                         r"got \[0.5, 0.5, 0.0\]"):
        library_plan(probs, library, [np.array([0.5, 0.5, 0.0]), np.array([0.8, 0.2])])
    with pytest.raises(ValueError, match=r"prior dimension 1 .* got \[0.8, 0.3\]"):
        library_plan(probs, library, [np.array([0.5, 0.25, 0.25]), np.array([0.8, 0.3])])
    with pytest.raises(ValueError, match=r"sizes \[3, 2\], got sizes \[\(3,\)\]"):
        library_plan(probs, library, [np.array([0.5, 0.25, 0.25])])
    with pytest.raises(ValueError, match="needs a plan library"):
        predict_plan(RepresentationNetwork(4, (3, 2)), np.zeros((1, 4)), prior=prior)
    # a zero probability does not make every score -inf
    assert library_plan([np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0]])], library).tolist() == [[0, 0]]


def test_plan_library_is_sorted_distinct_rows() -> None:
    assert plan_library([[2, 1], [0, 3], [2, 1]]).tolist() == [[0, 3], [2, 1]]
    libs = plan_libraries([[2, 1], [0, 3], [2, 1], [1, 1]], ["t", "u", "t", "u"])
    assert {k: v.tolist() for k, v in libs.items()} == {"t": [[2, 1]], "u": [[0, 3], [1, 1]]}
    with pytest.raises(ValueError, match="differ in length: 2 != 1"):
        plan_libraries([[0, 1], [1, 0]], ["t"])
    with pytest.raises(ValueError, match=r"\(N >= 1, n\), got \(0,\)"):
        plan_library([])


@pytest.mark.parametrize(("library", "match"), [
    (np.array([0, 1]), r"shape \(K >= 1, 2\), got \(2,\)"),
    (np.zeros((0, 2), dtype=int), r"got \(0, 2\)"),
    (np.array([[0.0, 1.0]]), "integer choices, got dtype float64"),
    (np.array([[0, 1], [3, 0]]), "row 1 has choice 3 for dimension 0, which has 3 choices"),
])
def test_library_plan_rejects_bad_libraries(library: np.ndarray, match: str) -> None:
    probs = [np.full((1, 3), 1 / 3), np.full((1, 2), 0.5)]
    with pytest.raises(ValueError, match=match):
        library_plan(probs, library)


# ------------------------------------------------------------------ key dimensions and Fig 7


def test_key_dimensions_rule() -> None:
    agree = np.tile([0.1, 0.7, 0.1, 0.1], (10, 1))  # top mean 0.7 > 2/4
    disagree = np.eye(4)[np.arange(10) % 4] * 0.9 + 0.025  # confident per sample, mean ~uniform
    flat = np.full((10, 7), 1 / 7)
    s = key_dimensions([agree, disagree, flat])
    assert [d.key for d in s] == [True, False, False]
    assert s[0].top_choice == 1 and s[0].top_prob == pytest.approx(0.7) and s[0].threshold == 0.5
    assert s[1].mean_max_prob == pytest.approx(0.925) and s[1].top_prob < 0.5
    assert s[2].threshold == pytest.approx(2 / 7)


def test_plot_rn_probabilities(tmp_path: Path) -> None:
    from prl.plots import plot_rn_probabilities

    rng = np.random.default_rng(0)
    probs = {task: [rng.dirichlet(np.ones(m) * (0.3 if i % 2 else 5.0), size=20) for i, m in enumerate(RS_DIMS)]
             for task in ("hammer", "sweep")}
    names = [f"d{i}" for i in range(6)]
    choices = [[str(k) for k in range(m)] for m in RS_DIMS]
    fig = plot_rn_probabilities(probs, names, choices, tmp_path / "fig7.png")
    assert (tmp_path / "fig7.png").stat().st_size > 10_000
    assert len(fig.axes) == 2 * 6  # a row per task, a chart per dimension: what mlflow.log_figure logs
    with pytest.raises(ValueError, match="'hammer'"):
        plot_rn_probabilities({"hammer": probs["hammer"][:5]}, names, choices, tmp_path / "bad.png")
    long = "unscrew: prior, another dataset (seed 1), trained here"  # a row label experiments.proposal_rn draws
    fig = plot_rn_probabilities({long: probs["hammer"]}, names, choices, tmp_path / "long.png")
    label = fig.axes[0].yaxis.label
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    box, height = label.get_window_extent(renderer), fig.axes[0].get_window_extent(renderer).height
    assert "seed 1" in label.get_text() and box.x0 >= 0 and box.height <= height  # within its row


def test_pipeline_decodings_resolve_or_name_what_is_missing() -> None:
    from prl.plb import load_plb
    from prl.rn_policy import DECODINGS, decoding

    model = RepresentationNetwork(4)
    assert DECODINGS == ("rn", "rn_library", "rn_success")
    assert decoding(model, "hammer", "rn") == (None, None)
    with pytest.raises(ValueError, match=r"'rn_library' needs a plan library for task 'hammer'; the model has none"):
        decoding(model, "hammer", "rn_library")
    with pytest.raises(ValueError, match=r"unknown RN decoding 'greedy'; known: rn, rn_library, rn_success"):
        decoding(model, "hammer", "greedy")
    model.plan_libraries = {"hammer": np.array([[0, 3, 3, 0, 0, 1]])}
    library, prior = decoding(model, "hammer", "rn_library")
    assert library.tolist() == [[0, 3, 3, 0, 0, 1]] and prior is None
    library, prior = decoding(model, "hammer", "rn_success")  # no stored prior: the catalogue's
    assert [p.tolist() for p in prior] == [p.tolist() for p in load_plb().prior("hammer")]
    stored = tuple(np.full(m, 1.0 / m) for m in RS_DIMS)
    model.plan_priors = {"hammer": stored}  # the prior the demos were sampled with wins over the catalogue
    assert decoding(model, "hammer", "rn_success")[1] is stored


def test_pointnet_digest_is_checked(tmp_path: Path) -> None:
    import hashlib

    from prl.rn_policy import check_pointnet
    from prl.version import file_digest

    model = RepresentationNetwork(4)
    (tmp_path / "pn.pt").write_bytes(b"pointnet")
    (tmp_path / "other.pt").write_bytes(b"another pointnet")
    check_pointnet(model, tmp_path / "other.pt")  # an RN that records none accepts any
    model.pointnet_sha256 = file_digest(tmp_path / "pn.pt")
    assert model.pointnet_sha256 == hashlib.sha256(b"pointnet").hexdigest()
    check_pointnet(model, tmp_path / "pn.pt")
    with pytest.raises(ValueError, match=r"other.pt \(sha256 [0-9a-f]{12}\) is not the one this RN was trained with"):
        check_pointnet(model, tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        check_pointnet(model, tmp_path / "missing.pt")
