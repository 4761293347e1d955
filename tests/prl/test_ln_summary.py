"""Committed LN point summaries: their one byte form, errors naming a malformed file, the reuse decision and the
demonstrations' digest (``prl.ln_summary``), on the tiny fixture summaries of ``tests/fixtures/ln``."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest

from prl.ln_summary import (
    RECORD_KEYS,
    SummaryError,
    compact,
    demonstrations_digest,
    read_summaries,
    read_summary,
    reuse_decision,
    summary_bytes,
    thin_rows,
    write_summary,
)

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "ln"
ONE = FIXTURES / "ln-hammer-physics-k1280-seed0-t3200.json"


def record_of(summary: dict) -> dict:
    return {k: copy.deepcopy(summary[k]) for k in RECORD_KEYS}


def test_fixtures_are_in_their_one_byte_form(tmp_path: Path) -> None:
    summaries = read_summaries(FIXTURES)
    assert sorted(summaries) == sorted(p.stem for p in FIXTURES.glob("ln-*.json")) and len(summaries) == 5
    assert (FIXTURES / "reference-hammer.json").is_file()  # a reference plans' file is not a point summary
    for stem, s in summaries.items():
        assert (FIXTURES / f"{stem}.json").read_bytes() == summary_bytes(s)
        path = write_summary(tmp_path, s)  # written again: the same bytes
        assert path.name == f"{stem}.json" and path.read_bytes() == (FIXTURES / path.name).read_bytes()
    text = ONE.read_text()
    assert text.startswith("{\n \"code_version\"") and text.endswith("}\n")  # sorted keys, indent 1


def test_a_summary_that_names_its_method_variant_still_loads(tmp_path: Path) -> None:
    """Summaries written before the LN's methods were called methods name them ``point.variant``: read as
    ``point.method``, the same summary as the fixture's."""
    old = json.loads(ONE.read_text())
    old["point"]["variant"] = old["point"].pop("method")
    path = tmp_path / ONE.name
    path.write_text(json.dumps(old))
    assert read_summary(path) == read_summary(ONE)
    assert read_summary(path)["point"] == {"task": "hammer", "method": "physics", "demo_steps": 1280, "seed": 0}


def test_compact_rounds_curves_not_settings() -> None:
    import numpy as np

    assert compact({"a": 0.123456, "b": (1, 2.00004), "c": float("nan"), "d": np.float32(0.5), "e": True}) == \
        {"a": 0.1235, "b": [1, 2.0], "c": None, "d": 0.5, "e": True}
    assert compact(1e-05, None) == 1e-05 and compact(1e-05) == 0.0
    s = read_summary(ONE)
    assert s["settings"]["sb3.rms_prop_eps"] == 1e-05  # settings are written whole
    with pytest.raises(TypeError, match="JSON values only"):
        compact({"p": Path("/x")})


def test_long_curves_are_thinned_evenly_with_both_ends() -> None:
    assert thin_rows(list(range(10)), 4) == [0, 3, 6, 9]  # rows i * 9 / 3
    assert thin_rows(list(range(7)), 3) == [0, 3, 6]
    assert thin_rows(list(range(5)), 5) == [0, 1, 2, 3, 4]  # short curves whole
    assert len(thin_rows(list(range(3850)))) == 400  # joint control at the plan runs' frames
    with pytest.raises(ValueError, match="max_rows must be an integer >= 2, got 1"):
        thin_rows([1, 2, 3], 1)


def test_absolute_local_paths_are_refused(tmp_path: Path) -> None:
    s = read_summary(ONE)
    s["settings"]["pointnet"] = "/home/someone/outputs/models/pointnet.pt"
    with pytest.raises(SummaryError, match="local absolute path.*/home/someone"):
        write_summary(tmp_path, s)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("edit", "match"), [
    (lambda s: s.pop("code_version"), "missing key 'code_version'"),
    (lambda s: s["eval"].pop("outcomes"), "missing key 'eval.outcomes'"),
    (lambda s: s["point"].update(seed="0"), "'point.seed' must be an integer, got '0'"),
    (lambda s: s.update(timesteps=True), "'timesteps' must be an integer, got True"),
    (lambda s: s["rows"][1].pop("frames"), r"missing key 'rows\[1\].frames'"),
    (lambda s: s["eval"].update(successes=3), "eval says 3/4 but its outcomes hold 4/4"),
    (lambda s: s.update(name="ln-hammer-physics-k1280-seed9"), "is not its point's"),
    (lambda s: s.update(timesteps=640), "belongs in a file named 'ln-hammer-physics-k1280-seed0-t640.json'"),
])
def test_a_malformed_summary_is_named(tmp_path: Path, edit, match: str) -> None:
    s = json.loads(ONE.read_text())
    edit(s)
    path = tmp_path / ONE.name
    path.write_text(json.dumps(s))
    with pytest.raises(SummaryError, match=match) as info:
        read_summary(path)
    assert str(path) in str(info.value)


def test_bad_json_missing_and_empty_directories_are_named(tmp_path: Path) -> None:
    shutil.copytree(FIXTURES, tmp_path / "ln")
    bad = tmp_path / "ln" / "ln-hammer-joint-k0-seed0-t3200.json"
    bad.write_text(bad.read_text()[:-20])
    with pytest.raises(SummaryError, match="not valid JSON") as info:
        read_summaries(tmp_path / "ln")
    assert str(bad) in str(info.value)
    with pytest.raises(FileNotFoundError, match="no LN summaries directory at .*nowhere"):
        read_summaries(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"no LN summary \(\*.json\) in .*empty"):
        read_summaries(tmp_path / "empty")
    with pytest.raises(SummaryError, match="no such summary file"):
        read_summary(tmp_path / "missing.json")


def test_a_summary_is_reused_only_for_the_same_point_settings_code_and_data() -> None:
    s = read_summary(ONE)
    same = record_of(s)
    same["settings"]["ln.hidden"] = (256, 256)  # a tuple in today's config, a list in the file: the same
    assert reuse_decision(s, same) == (True, "same point, timesteps, settings and code version")
    assert reuse_decision(None, same) == (False, "no summary yet")
    other = record_of(s)
    other["settings"]["ln.learning_rate"] = 0.001
    other["settings"]["n_frames"] = 1500
    reuse, why = reuse_decision(s, other)
    assert not reuse and why == "settings differ: ln.learning_rate 0.0007 -> 0.001; n_frames 750 -> 1500"
    other = record_of(s)
    other["settings"]["ln.extra_flag"] = 1
    assert reuse_decision(s, other) == (False, "settings differ: ln.extra_flag '(absent)' -> 1")
    # the demonstrations' bytes are recorded, not compared: a new machine regenerates the same recipe with a few
    # other PhysX outcomes (prl.ln_summary); the recipe is a setting
    assert reuse_decision(s, {**record_of(s), "dataset_digest": "0123456789abcdef"})[0]
    for key, value in (("code_version", "ffffffffffffffff"), ("timesteps", 640)):
        other = {**record_of(s), key: value}
        reuse, why = reuse_decision(s, other)
        assert not reuse and why.startswith(f"{key} ") and repr(value) in why
    with pytest.raises(ValueError, match="lacks"):
        reuse_decision(s, {"point": s["point"]})


def test_demonstrations_digest() -> None:
    import numpy as np

    seeds, plans, rewards = [5, 7], [[0, 3, 2, 0, 0, 1], [1, 3, 2, 0, 0, 1]], np.array([2.1, 3.0], np.float32)
    d = demonstrations_digest("hammer", seeds, plans, rewards)
    assert len(d) == 16 and d == demonstrations_digest("hammer", seeds, np.array(plans), list(rewards))
    assert d != demonstrations_digest("sweep", seeds, plans, rewards)
    assert d != demonstrations_digest("hammer", [5, 8], plans, rewards)
    assert d != demonstrations_digest("hammer", seeds, plans, np.array([2.1, 3.5], np.float32))
    assert d != demonstrations_digest("hammer", seeds, plans[::-1], rewards)  # dataset order counts
    weighted = demonstrations_digest("hammer", seeds, plans, rewards, {"weight": np.ones(2, np.float32)})
    assert weighted != d and weighted != demonstrations_digest("hammer", seeds, plans, rewards,
                                                               {"weight": np.array([1.0, 0.5])})
    with pytest.raises(ValueError, match="2 seeds but 1 rewards"):
        demonstrations_digest("hammer", seeds, plans, rewards[:1])
