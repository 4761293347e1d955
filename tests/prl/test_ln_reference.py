"""The reference plans' committed summaries (``prl.ln_reference``): their one byte form, their checks naming the
file, and when the command keeps one; on the hand-written fixture ``tests/fixtures/ln/reference-hammer.json``."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from prl.ln_reference import (
    REFERENCE_RECORD_KEYS,
    plan_result,
    read_reference,
    read_references,
    reference_kinds,
    reference_label,
    reference_note,
    reference_reuse,
    reference_rows,
    reference_seeds,
    write_reference,
)
from prl.ln_summary import SummaryError

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "ln"
REFERENCE = FIXTURES / "reference-hammer.json"


def record_of(ref: dict) -> dict:
    return {k: copy.deepcopy(ref[k]) for k in REFERENCE_RECORD_KEYS}


def test_the_fixture_is_in_its_one_byte_form(tmp_path: Path) -> None:
    ref = read_reference(REFERENCE)
    assert write_reference(tmp_path, ref).read_bytes() == REFERENCE.read_bytes()
    assert REFERENCE.read_text().startswith("{\n \"code_version\"")  # sorted keys, indent 1
    assert list(read_references(FIXTURES)) == ["hammer"] and read_references(tmp_path / "nowhere") == {}
    assert reference_seeds(ref) == [10_000_000, 10_000_001, 10_000_002, 10_000_003]


def test_plan_result_counts_and_rounds() -> None:
    outs = [SimpleNamespace(seed=5, plan=(0, 3, 2, 0, 0, 1), success=True, measure=2.345678, error=""),
            SimpleNamespace(seed=6, plan=(1, 3, 2, 0, 0, 1), success=False, measure=0.0, error="PhysX: boom")]
    r = plan_result(outs)
    assert (r["successes"], r["n"], r["ci95"]) == (1, 2, [0.0945, 0.9055])  # Wilson of 1/2
    assert r["outcomes"][0] == {"seed": 5, "plan": [0, 3, 2, 0, 0, 1], "success": True, "measure": 2.3457,
                                "error": ""}
    with pytest.raises(ValueError, match="at least one outcome"):
        plan_result([])


@pytest.mark.parametrize(("edit", "match"), [
    (lambda r: r.pop("code_version"), "missing key 'code_version'"),
    (lambda r: r["settings"].pop("eval_scenes"), "missing key 'settings.eval_scenes'"),
    (lambda r: r["plans"].pop("prior"), r"missing \['prior'\]"),
    (lambda r: r["plans"].update(uniform=r["plans"]["prior"]), r"unknown \['uniform'\]"),
    (lambda r: r["settings"].pop("rn"), "settings.rn is missing"),
    (lambda r: r["plans"]["rn"]["outcomes"][1].update(success="yes"), r"'plans.rn.outcomes\[1\].success' must be"),
    (lambda r: r["plans"]["expert"].update(successes=3), "plans.expert says 3/4 but its outcomes hold 4/4"),
    (lambda r: r["settings"].update(eval_scenes=5), "plans.expert has 4 outcomes, settings.eval_scenes is 5"),
    (lambda r: r["plans"]["prior"]["outcomes"][0].update(seed=7), "plans.prior ran on other scenes than"),
    (lambda r: r.update(task="sweep"), "belongs in a file named 'reference-sweep.json'"),
    (lambda r: r["plans"].update({"family x expert": r["plans"]["prior"]}), r"unknown \['family x expert'\]"),
    (lambda r: r["plans"].update({"family 1 expert": {**r["plans"]["prior"], "n": 3}}),
     r"plans.family 1 expert says 1/3 but"),
    (lambda r: r["plans"].update(best_fixed=r["plans"]["expert"]), "settings.best_fixed is missing"),
    (lambda r: r["settings"].update(best_fixed=[0, 3, 2, 0, 0, 1]), "the plans have no best_fixed"),
    (lambda r: r.update(plans={**r["plans"], "best_fixed": r["plans"]["prior"]},
                        settings={**r["settings"], "best_fixed": [0, 3, 2, 0, 0, 1]}),
     r"plans.best_fixed ran \[\d, \d, \d, \d, \d, \d\], settings.best_fixed is \[0, 3, 2, 0, 0, 1\]"),
])
def test_a_malformed_reference_is_named(tmp_path: Path, edit, match: str) -> None:
    ref = json.loads(REFERENCE.read_text())
    edit(ref)
    path = tmp_path / REFERENCE.name
    path.write_text(json.dumps(ref))
    with pytest.raises(SummaryError, match=match) as info:
        read_reference(path)
    assert str(path) in str(info.value)


def test_not_json_missing_and_absolute_paths_are_named(tmp_path: Path) -> None:
    (tmp_path / "reference-hammer.json").write_text("{")
    with pytest.raises(SummaryError, match="reference-hammer.json.*not valid JSON"):
        read_references(tmp_path)
    with pytest.raises(SummaryError, match="reference-sweep.json.*no such reference file"):
        read_reference(tmp_path / "reference-sweep.json")
    ref = read_reference(REFERENCE)
    ref["settings"]["rn"] = "/home/someone/outputs/models/rn-seed0.pt"
    with pytest.raises(SummaryError, match="local absolute path.*/home/someone"):
        write_reference(tmp_path / "out", ref)
    assert not (tmp_path / "out").exists()


def test_a_reference_is_kept_only_for_the_same_task_settings_and_code() -> None:
    ref = read_reference(REFERENCE)
    same = record_of(ref)
    assert reference_reuse(ref, same) == (True, "same task, settings and code version")
    assert reference_reuse(None, same) == (False, "no summary yet")
    more = copy.deepcopy(same)
    more["settings"]["eval_scenes"] = 50
    assert reference_reuse(ref, more) == (False, "settings differ: eval_scenes 4 -> 50")
    without_rn = copy.deepcopy(same)
    del without_rn["settings"]["rn"]
    assert reference_reuse(ref, without_rn) == (False, "settings differ: rn 'rn-seed0.pt' -> '(absent)'")
    assert reference_reuse(ref, {**same, "code_version": "ffffffffffffffff"}) == \
        (False, "code_version 'd0c146fe91b77c68' -> 'ffffffffffffffff'")
    assert reference_reuse(ref, {**same, "started": "another day"})[0]  # when it ran is recorded, not compared
    with pytest.raises(ValueError, match="lacks"):
        reference_reuse(ref, {"task": "hammer"})


def test_a_mixed_variants_kinds_are_kept_in_the_reports_order(tmp_path: Path) -> None:
    """The family oracle and each family's expert (envs.families) are reference kinds: checked like the others,
    ordered after the expert, the prior and the RN, families by index (10 after 2)."""
    ref = json.loads(REFERENCE.read_text())
    for kind in ("family 10 expert", "oracle", "family 2 expert"):
        ref["plans"][kind] = copy.deepcopy(ref["plans"]["prior"])
    path = tmp_path / REFERENCE.name
    path.write_text(json.dumps(ref))
    assert reference_kinds(read_reference(path)["plans"]) == ["expert", "prior", "rn", "oracle", "family 2 expert",
                                                              "family 10 expert"]
    assert reference_label("family 2 expert") == "family 2's expert plan"
    assert reference_label("oracle").startswith("family oracle")
    ref["plans"]["best_fixed"] = copy.deepcopy(ref["plans"]["expert"])
    ref["settings"]["best_fixed"] = ref["plans"]["expert"]["outcomes"][0]["plan"]
    path.write_text(json.dumps(ref))
    assert reference_kinds(read_reference(path)["plans"])[3:5] == ["oracle", "best_fixed"]
    note = reference_note(ref, [])
    assert f"the best fixed plan its search found (`{ref['settings']['best_fixed']}`" in note
    assert reference_rows(ref)[4].startswith("| best fixed plan of the variant search (reference) | - | 4/4 |")
