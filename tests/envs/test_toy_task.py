"""A task kept outside ``envs/tasks`` joins the pipeline by being imported, and touches no other task.

The toy task ``nudge`` (``tests/toy_tasks/nudge.py``: the sweep's scene, success = one swept cube in the zone, its
catalogue entry declared on its class) is imported by file path, as a user's own task module would be; no list
anywhere else names it. The first tests check the registry's side: the task is found, declared as a base task,
accepted by the config, and its module enters its own outcome version while every other task's version and
catalogue view stay as they were (so adding a task never makes the committed LN results of the others stale).
The last ones run the pipeline's stages on it with few scenes: trials of its expert plan, one synthesis shard, the
labels recovered from the demo, the LeRobot export and its reload, and the RN's features x.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.sim

REPO = Path(__file__).resolve().parents[2]
TOY_FILE = REPO / "tests" / "toy_tasks" / "nudge.py"
TOY_MODULE = "toy_nudge"
RUN_SEED = 1
"""The synthesis run's seed: its shard keeps the demo of attempt 0, which swept exactly one cube into the zone
(measured: a success under the toy's rule that the sweep's, more than three cubes, would have failed)."""


@pytest.fixture(scope="module")
def toy() -> Iterator[tuple[ModuleType, dict[str, str]]]:
    """The toy module, imported by file path, and every other known task's ``outcome_version`` computed before
    the import. Importing the module is all it takes: its class declares itself when defined. Afterwards the toy is
    forgotten again (its environment unregistered, its declaration dropped), so later tests see the repository's
    tasks only."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    from prl import task_registry
    from prl.version import outcome_version

    before = {t: outcome_version(t) for t in task_registry.known_tasks() if t != "nudge"}
    spec = importlib.util.spec_from_file_location(TOY_MODULE, TOY_FILE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[TOY_MODULE] = module
    spec.loader.exec_module(module)
    assert "nudge" in task_registry.known_tasks()  # declared by the import alone, before any look-up
    yield module, before
    REGISTERED_ENVS.pop(module.ENV_ID, None)
    task_registry._DECLARED.pop("nudge", None)
    sys.modules.pop(TOY_MODULE, None)


def test_the_toy_is_declared_by_its_module_alone(toy) -> None:
    """Importing the toy module makes ``nudge`` a task everywhere the pipeline asks (the environment ids, the
    registry's known tasks, the config's validation), declared as a base task (its name has no underscore: it
    reuses the sweep's scene by inheritance, it is no variant of it). Its outcome version covers its own file and
    the sweep module it imports, while no other task's version moved: the toy's file is in no other task's files."""
    import envs.tasks as T
    from prl.config import make_config
    from prl.task_registry import declared, known_tasks
    from prl.version import outcome_files, outcome_version

    module, before = toy
    assert T.TASK_ENV_IDS["nudge"] == module.ENV_ID
    assert "nudge" in known_tasks()
    assert make_config(tasks=["nudge"]).tasks == ("nudge",)
    decl = declared()["nudge"]
    assert decl.base == ""
    assert decl.module_file == TOY_FILE.resolve()
    assert decl.measure_unit == "cubes" and decl.evidence == module.ToyNudgeEnv.evidence
    assert decl.meshes is not None  # the sweep's builders, inherited: the PointNet's points need them

    assert set(before) < set(known_tasks())
    after = {t: outcome_version(t) for t in before}
    assert after == before, f"tasks whose outcome version moved: {[t for t in before if after[t] != before[t]]}"
    files = outcome_files("nudge")
    assert "tests/toy_tasks/nudge.py" in files
    assert "envs/tasks/sweep.py" in files  # the scene it inherits decides its outcomes too
    assert all("tests/toy_tasks/nudge.py" not in outcome_files(t) for t in before)
    assert outcome_version("nudge") != outcome_version("sweep")


def with_entry(data: bytes, name: str, entry: dict[str, Any]) -> bytes:
    """``data`` (a PLB catalogue's bytes) with ``name``'s entry, written as YAML, inserted after the last entry
    of its ``tasks:`` section (wherever that section sits: the entry goes before the next top-level key), after a
    blank line and a comment of its own."""
    lines = data.splitlines(keepends=True)
    start = next(i + 1 for i, line in enumerate(lines) if line.rstrip() == b"tasks:")
    stop = next((i for i in range(start, len(lines)) if lines[i][:1].isalpha()), len(lines))
    end = stop
    while end > start and (not lines[end - 1].strip() or lines[end - 1].lstrip().startswith(b"#")):
        end -= 1  # the blank and comment lines above the next section stay with it
    if end and not lines[end - 1].endswith(b"\n"):
        lines[end - 1] += b"\n"
    text = yaml.safe_dump({name: {"texts": list(entry["texts"]), "prior": dict(entry["prior"])}},
                          sort_keys=False, default_flow_style=None, width=1000)
    block = [b"\n", b"  # the toy task of tests/toy_tasks/nudge.py\n"]
    block += [b"  " + line.encode() + b"\n" for line in text.splitlines()]
    return b"".join(lines[:end] + block + lines[end:])


@pytest.mark.parametrize("layout", ["as committed", "tasks section followed by another"])
def test_the_toy_catalogue_entry_changes_no_other_task_view(toy, layout: str) -> None:
    """Writing the toy's catalogue entry into ``assets/plb.yaml`` (as a user moving it out of the class would)
    leaves every other task's view of the catalogue, hence its outcome version, byte for byte as it was; the
    toy's own view gains its entry. Checked on the committed file and on one whose ``tasks:`` section is followed
    by another top-level key, where the entry goes inside the section, not at the end of the file; the result
    is YAML whose ``tasks.nudge`` is the class's entry."""
    from prl.task_registry import known_tasks
    from prl.version import catalogue_view

    module, _ = toy
    entry = module.ToyNudgeEnv.catalogue_entry
    old = (REPO / "assets" / "plb.yaml").read_bytes()
    if layout != "as committed":
        old = old.rstrip(b"\n") + b"\n\n# after the tasks\nnotes:\n  written_by: test_toy_task\n"
    new = with_entry(old, "nudge", entry)
    parsed = yaml.safe_load(new)
    assert parsed["tasks"]["nudge"] == {"texts": list(entry["texts"]), "prior": dict(entry["prior"])}
    assert parsed == {**yaml.safe_load(old), "tasks": parsed["tasks"]}  # nothing else moved
    assert set(parsed["tasks"]) == {*yaml.safe_load(old)["tasks"], "nudge"}
    others = [t for t in known_tasks() if t != "nudge"]
    assert others
    changed = [t for t in others if catalogue_view(new, t) != catalogue_view(old, t)]
    assert not changed, f"adding the toy's entry changed the catalogue view of {changed}"
    assert b"  nudge:" in catalogue_view(new, "nudge") and b"  nudge:" not in catalogue_view(old, "nudge")


def test_the_catalogue_reads_the_toy_texts_and_names_break_the_underscore_rule(toy) -> None:
    """``load_plb()`` has no entry ``nudge`` in its file and reads the class's (texts and the sweep's prior,
    which the toy copies); a base task named with an underscore is refused with a message naming it."""
    from prl.plb import load_plb
    from prl.task_registry import DeclarationError, check_name

    module, _ = toy
    plb = load_plb()
    assert plb.texts("nudge") == tuple(module.ToyNudgeEnv.catalogue_entry["texts"])
    assert plb.texts("nudge") != plb.texts("sweep")
    for mine, sweep in zip(plb.prior("nudge"), plb.prior("sweep"), strict=True):
        np.testing.assert_allclose(mine, sweep)
    with pytest.raises(DeclarationError, match="'my_task'"):
        check_name("my_task")
    check_name("mytask")  # the name the message proposes is fine


def test_expert_trials_measure_the_toy_rule(toy) -> None:
    """The toy's expert plan (the sweep's, inherited) on two trial scenes: measured 2 of 2 successes (4 of 4 on
    the first four scenes, 6 to 8 cubes swept), so at least 1 of 2 must succeed; every outcome's success is the
    toy's rule, one cube or more in the zone without a failure, read from the simulated state."""
    from envs.tasks import task_class
    from envs.trials import run_trials, trial_scene_seeds

    cls = task_class("nudge")
    assert cls is toy[0].ToyNudgeEnv
    outcomes = run_trials("nudge", [cls.expert_plan] * 2, trial_scene_seeds(0, 2), progress=False)
    assert [o.task for o in outcomes] == ["nudge", "nudge"]
    assert not [o.error for o in outcomes if o.error]
    assert sum(o.success for o in outcomes) >= 1, outcomes
    for o in outcomes:
        assert o.measure == o.outcome["cubes_in_zone"]
        assert o.success == (o.measure >= 1.0 and not o.fail)


@pytest.fixture(scope="module")
def shard(toy, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """One synthesis shard of the toy keeping one demo (run seed ``RUN_SEED``)."""
    from envs.synthesis import ShardSpec, run_shard

    return run_shard(ShardSpec("nudge", 0, 1, RUN_SEED, tmp_path_factory.mktemp("synthesis")))


@pytest.fixture(scope="module")
def labels(shard) -> dict[str, list[int]]:
    """The label stage's recovered plan of each demo (``flows.recover_labels``: ``recover_plan`` on the
    recording), keyed by its path."""
    from prl.demo import load_demo
    from prl.label_recovery import recover_plan
    from prl.plb import load_plb

    return {str(p): [int(v) for v in recover_plan(load_demo(p), load_plb()).plan] for p in shard.demo_paths}


def test_a_synthesis_shard_keeps_a_toy_demo_and_its_labels(toy, shard, labels) -> None:
    """The shard keeps its one success, a demo of ``nudge`` with a sentence of the toy's own catalogue texts;
    its recorded outcome swept exactly one cube in (measured), which only the toy's rule calls a success. Its
    recovered label is a full label (a valid choice on every dimension), and agrees with the commanded plan on at
    least 4 of 6 dimensions (measured: 5, the grasp pattern read as its neighbour)."""
    from prl.demo import load_demo
    from prl.plb import load_plb

    assert (shard.task, shard.successes, len(shard.demo_paths), shard.errors) == ("nudge", 1, 1, 0)
    demo = load_demo(shard.demo_paths[0])
    assert demo.task == "nudge" and demo.success
    assert demo.text in toy[0].ToyNudgeEnv.catalogue_entry["texts"]
    assert demo.outcome["cubes_in_zone"] == 1.0
    label = labels[str(shard.demo_paths[0])]
    sizes = load_plb().sizes
    assert len(label) == len(sizes) and all(0 <= v < s for v, s in zip(label, sizes, strict=True)), label
    assert sum(int(a == b) for a, b in zip(label, demo.plan, strict=True)) >= 4, (label, demo.plan)


@pytest.fixture(scope="module")
def dataset(shard, labels, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The LeRobot export of the shard's demos with their labels, as ``flows.export_dataset`` writes it."""
    from prl.export import export_lerobot

    root = tmp_path_factory.mktemp("datasets") / "nudge-seed1"
    return export_lerobot(list(shard.demo_paths), root, repo_id="prl/nudge", per_episode_label=labels)


def test_the_export_holds_the_toy_episode_and_reloads(shard, dataset) -> None:
    """The export validates and reloads offline with LeRobot: one episode of the demo's length, the demo's
    sentence as its task, labelled, and a scene record naming the task ``nudge``."""
    from prl.demo import load_demo
    from prl.export_check import load_local
    from prl.export_schema import read_scenes

    demo = load_demo(shard.demo_paths[0])
    assert (dataset.n_episodes, dataset.tasks, dataset.n_labelled) == (1, (demo.text,), 1)
    assert dataset.checked_against_demos
    ds = load_local(dataset.root, "prl/nudge")
    assert ds.meta.total_episodes == 1 and len(ds) == dataset.n_frames == dataset.episode_lengths[0]
    assert list(ds.meta.episodes["tasks"][0]) == [demo.text]
    scenes = read_scenes(dataset.root)
    assert [(s["task"], s["seed"]) for s in scenes] == [("nudge", demo.seed)]


def test_features_of_the_toy_dataset(toy, shard, labels, dataset, pointnet_path: Path) -> None:
    """The RN's inputs read back from the export: the task, commanded plan and recovered label of the demo; x has
    the feature layout's width, its text part is the embedding of the demo's sentence (one of the toy's catalogue
    texts, not the sweep's), and its point parts are the tiny PointNet's features of the sweep's meshes."""
    from prl.demo import load_demo
    from prl.features import FEATURE_LAYOUT, episode_features, read_episodes
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet
    from prl.text_embed import embed_texts

    demo = load_demo(shard.demo_paths[0])
    episodes = read_episodes(dataset.root, "prl/nudge")
    assert episodes.tasks == ("nudge",) and episodes.texts == (demo.text,)
    assert episodes.plan.tolist() == [list(demo.plan)]
    assert episodes.label.tolist() == [labels[str(shard.demo_paths[0])]]
    np.testing.assert_allclose(episodes.x_manip[0], demo.x_manip, rtol=1e-6)

    pointnet = load_pointnet(pointnet_path)
    x = episode_features(episodes, pointnet, n_points=pointnet.cfg.n_points)
    assert x.shape == (1, FEATURE_LAYOUT.dim) and np.all(np.isfinite(x))
    toy_texts = list(toy[0].ToyNudgeEnv.catalogue_entry["texts"])
    text_part = x[0, FEATURE_LAYOUT.slice("text")]
    catalogue = embed_texts(toy_texts + list(load_plb().texts("sweep")))
    nearest = int(np.argmax(catalogue @ text_part))
    assert nearest < len(toy_texts) and toy_texts[nearest] == demo.text
    np.testing.assert_allclose(text_part, catalogue[nearest], atol=1e-5)
    for part in ("tool_points", "object_points"):
        assert np.any(x[0, FEATURE_LAYOUT.slice(part)] != 0), part


def test_the_task_lists_agree() -> None:
    """The environment ids, the registry's known tasks (read as text, without the simulator) and its declarations
    name the same tasks in the same order, the paper's four first; each task's class declares what the pipeline
    reads (a variant inherits its task's meshes and evidence)."""
    import envs.tasks as T
    from envs.red_team import evidence
    from prl.task_registry import TASKS_DIR, declared, known_tasks, repo_task_names

    assert tuple(T.TASK_ENV_IDS) == known_tasks() == tuple(declared())
    # the toy, when this module imported it already, is the one task kept outside envs/tasks
    assert repo_task_names() == tuple(t for t, d in declared().items() if d.module_file.parent == TASKS_DIR)
    assert known_tasks()[:4] == ("hammer", "sweep", "unscrew", "tweeze")
    assert {t: d.base for t, d in declared().items() if d.base} == {
        "hammer_mixed": "hammer", "sweep_mixed": "sweep", "tweeze_mixed": "tweeze", "unscrew_mixed": "unscrew"}
    assert all(d.meshes is not None and d.evidence and d.env_id == T.TASK_ENV_IDS[t] for t, d in declared().items())
    assert evidence("unscrew_mixed") == evidence("unscrew") == ("cap_turn_deg", "grasp_turn_deg", "cap_angle_deg",
                                                                "gripped")
