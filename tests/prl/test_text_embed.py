"""Task-text embeddings TE (prl.text_embed): the bundled all-MiniLM-L6-v2, offline."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prl import text_embed as T
from prl.plb import load_plb


@pytest.fixture(scope="module")
def texts() -> dict[str, tuple[str, ...]]:
    torch.set_num_threads(1)
    bank = load_plb()
    return {task: bank.texts(task) for task in ("hammer", "tweeze")}


def test_shape_dtype_and_unit_norm(texts):
    emb = T.embed_texts(texts["hammer"])
    assert emb.shape == (len(texts["hammer"]), T.TE_DIM) == (4, 384)
    assert emb.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)


def test_hammer_phrasings_closer_than_hammer_and_tweezers(texts):
    hammer = T.embed_texts(texts["hammer"])
    tweeze = T.embed_texts(texts["tweeze"])
    same = hammer @ hammer.T
    cross = hammer @ tweeze.T
    assert same[0, 1] > cross[0, 0]
    within = same[np.triu_indices(len(hammer), k=1)]
    assert within.min() > cross.max(), (within.min(), cross.max())  # measured 0.74 vs 0.48


def test_deterministic_and_independent_of_batch(texts):
    first = T.embed_texts(texts["hammer"])
    np.testing.assert_array_equal(first, T.embed_texts(texts["hammer"]))
    alone = T.embed_texts([texts["hammer"][2]])
    np.testing.assert_allclose(alone[0], first[2], atol=1e-5)


@pytest.mark.parametrize(("bad", "match"), [([], "empty"), (["ok", 3], r"texts\[1\]"), (["  "], "blank"),
                                            ("a hammer", "single string")])
def test_bad_input_raises_value_error(bad, match):
    with pytest.raises(ValueError, match=match):
        T.embed_texts(bad)


def test_model_info_names_the_bundled_model():
    info = T.model_info()
    assert info["name"] == "sentence-transformers/all-MiniLM-L6-v2"
    assert info["dim"] == T.TE_DIM
    assert info["package_version"].count(".") >= 1
    assert (T.model_dir() / "model.safetensors").is_file()
