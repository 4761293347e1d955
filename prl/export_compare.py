"""Two LeRobot datasets compared file by file: ``fast_writes`` must write the files lerobot's own writes do.

A dataset's files are read as bytes, but for a parquet file as its table and schema metadata with ``datasets``'
fingerprint left out: lerobot's image-embedding pass (a ``datasets.map``) stamps one, and the fast path, which skips
that pass, does not. ``tests/prl/test_export.py`` and ``bench/bench_export.py`` compare the export's modes with it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path


def dataset_files(root: Path) -> dict[str, object]:
    """Every file of the dataset at ``root`` by its relative path: its bytes, or for a parquet file the pair (its
    table without schema metadata, the schema metadata without ``datasets``' fingerprint)."""
    import pyarrow.parquet as pq  # heavy: pyarrow, only to compare

    out: dict[str, object] = {}
    for p in sorted(Path(root).rglob("*")):
        if not p.is_file():
            continue
        if p.suffix != ".parquet":
            out[str(p.relative_to(root))] = p.read_bytes()
            continue
        table = pq.read_table(p)
        meta = dict(table.schema.metadata or {})
        if b"huggingface" in meta:
            hf = json.loads(meta[b"huggingface"])
            hf.pop("fingerprint", None)
            meta[b"huggingface"] = json.dumps(hf, sort_keys=True).encode()
        out[str(p.relative_to(root))] = (table.replace_schema_metadata(None), meta)
    return out


def same_file(a: object, b: object) -> bool:
    """Whether two entries of :func:`dataset_files` hold the same file (a missing file is ``None``)."""
    if isinstance(a, tuple) and isinstance(b, tuple):
        return a[0].equals(b[0]) and a[1] == b[1]
    return a == b


def differing_files(a: Mapping[str, object], b: Mapping[str, object]) -> list[str]:
    """The relative paths, sorted, whose files differ between two :func:`dataset_files` (or that one lacks)."""
    return sorted(k for k in a.keys() | b.keys() if not same_file(a.get(k), b.get(k)))
