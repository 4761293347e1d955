"""LeRobot export: round trip through ``LeRobotDataset``, atomic replacement, clear errors.

Fast tests use synthetic demos (random arrays saved with ``prl.demo.save_demo``); the ``sim``
tests export demos of real simulated episodes and reload them with lerobot.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lerobot")

from prl.constants import N_JOINTS, N_SENSORS, RECORD_HZ
from prl.export import export_key, export_lerobot, reusable_export, video_encoder
from prl.export_check import validate_lerobot
from prl.export_schema import (
    EXPORT_KEY_FILE,
    FEATURES,
    NO_LABEL,
    SCENES_FILE,
    VIDEO_CAMERAS,
    ExportError,
    VideoSpec,
    episode_frames,
    lerobot_features,
    video_key,
)

REPO_ID = "prl/hammer-test"
TEXT = "Hammer the nail down into the block."


@pytest.fixture(autouse=True)
def _private_datasets_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Reloading makes ``datasets`` copy the parquet files into its cache: keep those copies out of ~/.cache."""
    import datasets

    monkeypatch.setattr(datasets.config, "HF_DATASETS_CACHE", tmp_path_factory.mktemp("hf_datasets_cache"))


def _load_dataset(root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root)


def _synthetic_demo(seed: int, t: int):
    from prl.demo import X_MANIP_DIM, Demo

    rng = np.random.default_rng(seed)
    arrays = {
        "plan": rng.integers(0, 4, 6).astype(np.int64), "frame": np.arange(t) * 5,
        "stage": np.repeat(np.arange(7), -(-t // 7))[:t].astype(np.int64),
        "qpos": rng.normal(size=(t, N_JOINTS)), "qvel": rng.normal(size=(t, N_JOINTS)),
        "target": rng.normal(size=(t, N_JOINTS)), "force": rng.random((t, N_SENSORS)),
        "contact_pos": rng.normal(size=(t, N_SENSORS, 3)), "contact_normal": rng.normal(size=(t, N_SENSORS, 3)),
        "palm_pose": rng.normal(size=(t, 7)), "tool_pose": rng.normal(size=(t, 7)),
        "object_pose": rng.normal(size=(t, 7)), "anchors_at_grasp": rng.normal(size=(6, 3)),
        "gv_center": np.zeros(3), "gv_half": np.ones(3), "gv_rot": np.eye(3), "tool_gv_local": np.zeros(9),
        "tool_fv_local": np.zeros(9), "x_manip": rng.normal(size=X_MANIP_DIM).astype(np.float32),
        "scene_bodies": np.array(["hammer", "nail"]), "scene_pose": rng.normal(size=(t, 2, 7)),
        "scene_joints": np.array(["nail/nail_joint"]), "scene_qpos": rng.normal(size=(t, 1)),
    }
    return Demo(task="hammer", seed=seed, text=f"{TEXT} ({seed})", success=True, outcome={}, scene_params={},
                arrays=arrays)


@pytest.fixture
def synthetic_paths(tmp_path: Path) -> list[Path]:
    from prl.demo import save_demo

    return [save_demo(_synthetic_demo(seed, t), tmp_path / "demos" / f"ep{seed}.npz")
            for seed, t in ((1, 23), (2, 17))]


def _truncated_copy(src: Path, dst: Path) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])
    return dst


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(f.relative_to(root)): f.read_bytes() for f in sorted(root.rglob("*")) if f.is_file()}


def _dead_pid() -> int:
    """The id of a process that has exited (a killed exporter)."""
    out = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                         capture_output=True, text=True)
    return int(out.stdout)


def _siblings(root: Path) -> list[str]:
    return sorted(p.name for p in root.parent.iterdir() if p.name.startswith(f".{root.name}."))


# ----------------------------------------------------------------------------- fast tier


def test_features_declared_once_and_frames_match() -> None:
    assert lerobot_features().keys() == FEATURES.keys()
    assert lerobot_features()["observation.state"]["shape"] == (60,)
    demo = _synthetic_demo(3, 11)
    frames = episode_frames(demo, label=[1, 2, 3, 0, 0, 1])
    for name, spec in FEATURES.items():
        assert frames[name].dtype == np.dtype(spec["dtype"]), name
        assert frames[name].shape == (11, *spec["shape"]), name
    np.testing.assert_array_equal(frames["observation.contact_position"][4], demo.contact_pos[4].reshape(-1)
                                  .astype(np.float32))
    assert frames["label"][7].tolist() == [1, 2, 3, 0, 0, 1]
    assert episode_frames(demo)["label"][0].tolist() == [NO_LABEL] * 6
    with pytest.raises(ValueError, match="label must have shape"):
        episode_frames(demo, label=[1, 2])


def test_no_demo_paths_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no demo paths"):
        export_lerobot([], tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_missing_demo_is_named_and_nothing_written(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    missing = tmp_path / "demos" / "nope.npz"
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        export_lerobot([synthetic_paths[0], missing], tmp_path / "out" / "ds")
    assert not (tmp_path / "out").exists()


def test_unusable_destination(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(NotADirectoryError, match="not a directory"):
        export_lerobot(synthetic_paths, a_file)
    with pytest.raises(NotADirectoryError, match="not a directory"):
        export_lerobot(synthetic_paths, a_file / "ds")
    other = tmp_path / "someone_elses"
    other.mkdir()
    (other / "keep.txt").write_text("precious")
    with pytest.raises(ValueError, match="not a LeRobot dataset"):
        export_lerobot(synthetic_paths, other)
    assert (other / "keep.txt").read_text() == "precious"


def test_validate_refuses_a_non_dataset_without_creating_it(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="not a directory"):
        validate_lerobot(tmp_path / "absent", REPO_ID)
    assert not (tmp_path / "absent").exists()  # lerobot alone would mkdir it and go to the Hub
    (tmp_path / "empty").mkdir()
    with pytest.raises(ExportError, match="info.json"):
        validate_lerobot(tmp_path / "empty", REPO_ID)


def test_synthetic_round_trip_and_stale_staging_cleanup(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    from prl.demo import load_demo

    root = tmp_path / "out" / "ds"
    dead = _dead_pid()
    for stale in (root.parent / f".{root.name}.staging-{dead}", root.parent / f".{root.name}.staging-parts-{dead}"):
        (stale / "meta").mkdir(parents=True)  # left by a killed export (one process; several)
    report = export_lerobot(synthetic_paths, root, repo_id=REPO_ID, per_episode_label={2: [0, 1, 2, 3, 4, 5]})
    assert report.n_episodes == 2 and report.episode_lengths == (23, 17) and report.n_frames == 40
    assert report.n_labelled == 1 and report.checked_against_demos
    assert _siblings(root) == []
    ds = _load_dataset(root)
    d1 = load_demo(synthetic_paths[1])
    item = ds[23 + 5]
    assert int(item["episode_index"]) == 1 and int(item["frame_index"]) == 5
    np.testing.assert_allclose(item["observation.state"].numpy(), np.concatenate([d1.qpos[5], d1.qvel[5]]),
                               rtol=1e-6, atol=1e-6)
    assert item["label"].tolist() == [0, 1, 2, 3, 4, 5]
    assert ds[0]["label"].tolist() == [NO_LABEL] * 6
    assert item["task"] == d1.text


def test_fast_writes_give_lerobots_files(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    """``fast_writes`` (no embedding pass, prl's statistics, stats.json once, no fingerprint hashing, Arrow columns)
    writes the files lerobot's own writes do: the same bytes, and the same tables and parquet metadata (lerobot's
    embedding pass stamps a fingerprint the fast path does not); and lerobot's functions are back afterwards."""
    import datasets.arrow_dataset
    from lerobot.datasets import dataset_metadata

    from prl.export_compare import dataset_files, differing_files

    patched = (dataset_metadata.write_stats, datasets.arrow_dataset.generate_fingerprint,
               datasets.arrow_dataset.Dataset.__dict__["from_dict"])
    labels = {1: [0, 1, 2, 3, 4, 5]}
    slow = export_lerobot(synthetic_paths, tmp_path / "slow", repo_id=REPO_ID, per_episode_label=labels,
                          fast_writes=False)
    fast = export_lerobot(synthetic_paths, tmp_path / "fast", repo_id=REPO_ID, per_episode_label=labels)
    want, got = dataset_files(slow.root), dataset_files(fast.root)
    assert "meta/stats.json" in got and sorted(got) == sorted(want)
    assert differing_files(want, got) == []
    assert (dataset_metadata.write_stats, datasets.arrow_dataset.generate_fingerprint,
            datasets.arrow_dataset.Dataset.__dict__["from_dict"]) == patched


def test_the_comparison_leaves_out_the_fingerprint_and_names_what_differs(tmp_path: Path) -> None:
    """``prl.export_compare``: a parquet file is its table and metadata but for ``datasets``' fingerprint; a file that
    one side lacks, other bytes, another table or other metadata differ."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    from prl.export_compare import dataset_files, differing_files

    def write(root: Path, fingerprint: str, values: list[int], info: bytes = b"{}", extra: bool = False) -> Path:
        (root / "data").mkdir(parents=True)
        hf = json.dumps({"info": {"features": {}}, "fingerprint": fingerprint}).encode()
        pq.write_table(pa.table({"x": values}).replace_schema_metadata({b"huggingface": hf}), root / "data" / "a.parquet")
        (root / "info.json").write_bytes(info)
        if extra:
            (root / "extra.txt").write_text("x")
        return root

    base = dataset_files(write(tmp_path / "a", "f1", [1, 2]))
    assert sorted(base) == ["data/a.parquet", "info.json"]
    assert differing_files(base, dataset_files(write(tmp_path / "b", "f2", [1, 2]))) == []
    assert differing_files(base, dataset_files(write(tmp_path / "c", "f1", [1, 3]))) == ["data/a.parquet"]
    assert differing_files(base, dataset_files(write(tmp_path / "d", "f1", [1, 2], b"{ }", True))) == \
        ["extra.txt", "info.json"]


@pytest.mark.filterwarnings("ignore:Conversion of an array with ndim > 0:DeprecationWarning")  # datasets' own path
def test_arrow_columns_give_datasets_own_table() -> None:
    """Numeric numpy columns handed to ``Dataset.from_dict`` as Arrow arrays give the table of its own per-row
    encoding: float64 rounded to float32, a (T, 1) column as T numbers; strings pass through; a wrong width is an
    error naming the column."""
    import datasets

    from prl.export import arrow_columns

    features = datasets.Features({"x": datasets.List(datasets.Value("float32"), length=2),
                                  "stage": datasets.Value("int64"), "t": datasets.Value("float32"),
                                  "task": datasets.Value("string")})
    mapping = {"x": np.array([[0.1, 0.2], [0.3, 1 / 3]]), "stage": np.array([[3], [4]]),
               "t": np.array([0.0, 1 / 30]), "task": ["a", "b"]}
    columns = arrow_columns(mapping, features)
    assert columns["task"] is mapping["task"]
    assert columns["x"].type.list_size == 2 and columns["stage"].to_pylist() == [3, 4]
    want = datasets.Dataset.from_dict(mapping, features=features).with_format("arrow")[:]
    got = datasets.Dataset.from_dict(columns, features=features).with_format("arrow")[:]
    assert got.equals(want, check_metadata=True)
    assert got.column("x").to_pylist()[1] == [np.float32(0.3), np.float32(1 / 3)]
    with pytest.raises(ValueError, match="column 'x': values of shape \\(2, 3\\)"):
        arrow_columns({"x": np.zeros((2, 3))}, features)


def test_export_parts_are_contiguous_and_even() -> None:
    from prl.export_merge import export_parts

    assert export_parts(10, 2, 4) == [range(5), range(5, 10)]
    assert export_parts(7, 3, 1) == [range(3), range(3, 5), range(5, 7)]
    assert export_parts(5, 2, 3) == [range(5)]  # two parts would hold under 3 episodes each
    assert export_parts(1, 4, 1) == [range(1)]
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        export_lerobot([Path("any.npz")], Path("never"), workers=0)


def test_a_parallel_export_holds_what_one_process_writes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Two worker processes and lerobot's merge give the same frames, episodes, tasks, scene records and statistics
    (to float rounding) as one process; nothing of the parts is left beside the dataset. Each export's progress
    bar counts its 5 episodes (the parts' count comes from their processes), and the merge and the reload check say
    when they start and end."""
    import json

    import pandas as pd

    import prl.export_merge
    from prl.demo import save_demo

    paths = [save_demo(_synthetic_demo(seed, t), tmp_path / "demos" / f"ep{seed}.npz")
             for seed, t in ((1, 23), (2, 17), (3, 9), (4, 30), (5, 12))]
    labels = {1: [0, 1, 2, 3, 4, 5], 4: [1, 1, 1, 1, 1, 1]}
    one = export_lerobot(paths, tmp_path / "one", repo_id=REPO_ID, per_episode_label=labels)
    monkeypatch.setattr(prl.export_merge, "PARALLEL_MIN_EPISODES", 2)  # 5 episodes: parts of 3 and 2
    two = export_lerobot(paths, tmp_path / "two", repo_id=REPO_ID, per_episode_label=labels, workers=2)
    assert (two.n_episodes, two.n_frames) == (one.n_episodes, one.n_frames) == (5, 91)
    assert _siblings(two.root) == []
    err = capsys.readouterr().err.replace("\r", "\n").splitlines()
    bars = [line for line in err if "episode" in line]
    assert any(line.startswith("export: 100%") and "5/5" in line for line in bars), bars
    assert any(line.startswith("export (2 processes): 100%") and "5/5" in line for line in bars), bars
    # the steps after the bars say when they start and end: the merge once, the reload check in each export
    assert sum(line.startswith("export: merging the 2 parts' 5 episodes: done in ") for line in err) == 1, err
    reloads = "export: reloading the 5 episodes with LeRobotDataset and checking them"
    assert sum(line == f"{reloads} ..." for line in err) == 2, err
    assert sum(line.startswith(f"{reloads}: done in ") for line in err) == 2, err

    def table(root: Path, pattern: str, key: str) -> pd.DataFrame:
        frames = [pd.read_parquet(f) for f in sorted(root.glob(pattern))]
        return pd.concat(frames).sort_values(key).reset_index(drop=True)

    a, b = table(one.root, "data/*/*.parquet", "index"), table(two.root, "data/*/*.parquet", "index")
    assert list(b.columns) == list(a.columns) and b["episode_index"].tolist() == sorted(b["episode_index"])
    for col in a.columns:
        assert np.array_equal(np.stack(a[col].to_numpy()), np.stack(b[col].to_numpy())), col
    keep = ["episode_index", "length", "tasks", "dataset_from_index", "dataset_to_index"]
    ea, eb = (table(r, "meta/episodes/*/*.parquet", "episode_index")[keep] for r in (one.root, two.root))
    assert ea.astype(str).equals(eb.astype(str))
    assert pd.read_parquet(one.root / "meta/tasks.parquet").equals(pd.read_parquet(two.root / "meta/tasks.parquet"))
    assert (one.root / SCENES_FILE).read_text() == (two.root / SCENES_FILE).read_text()
    sa, sb = (json.loads((r / "meta/stats.json").read_text()) for r in (one.root, two.root))
    assert sorted(sa) == sorted(sb)
    for feature, stats in sa.items():
        for name, value in stats.items():
            assert np.allclose(np.asarray(value, float), np.asarray(sb[feature][name], float), rtol=1e-5,
                               atol=1e-6), (feature, name)
    assert _load_dataset(two.root)[40]["index"].item() == 40  # lerobot reloads it


def test_lean_writes_write_the_last_stats_once_and_none_on_error(tmp_path: Path) -> None:
    from lerobot.datasets import dataset_metadata
    from lerobot.datasets.io_utils import load_stats

    from prl.export import _lean_writes

    with _lean_writes():
        for i in range(3):
            dataset_metadata.write_stats({"x": {"mean": np.array([float(i)])}}, tmp_path / "ok")
        assert not (tmp_path / "ok").exists()  # nothing written before the block ends
    assert load_stats(tmp_path / "ok")["x"]["mean"].tolist() == [2.0]
    with pytest.raises(RuntimeError, match="boom"), _lean_writes():
        dataset_metadata.write_stats({"x": {"mean": np.array([1.0])}}, tmp_path / "failed")
        raise RuntimeError("boom")
    assert not (tmp_path / "failed").exists()


def test_export_key_and_reuse(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    labels = {str(synthetic_paths[0]): [0, 1, 2, 3, 0, 1]}
    key = export_key(synthetic_paths, labels, REPO_ID, 100, "v1")
    assert key == export_key(list(synthetic_paths), dict(labels), REPO_ID, 100, "v1")  # a pure function
    changed = {  # every input the dataset is made from changes the key
        export_key(synthetic_paths[::-1], labels, REPO_ID, 100, "v1"),
        export_key(synthetic_paths, {str(synthetic_paths[0]): [0, 1, 2, 3, 0, 2]}, REPO_ID, 100, "v1"),
        export_key(synthetic_paths, labels, "prl/other", 100, "v1"),
        export_key(synthetic_paths, labels, REPO_ID, 50, "v1"),
        export_key(synthetic_paths, labels, REPO_ID, 100, "v2"),
    }
    assert key not in changed and len(changed) == 5
    root = tmp_path / "ds"
    assert reusable_export(root, REPO_ID, key) is None  # nothing there yet
    first = export_lerobot(synthetic_paths, root, repo_id=REPO_ID, per_episode_label=labels, key=key)
    assert (root / EXPORT_KEY_FILE).read_text().strip() == key and not first.reused
    again = reusable_export(root, REPO_ID, key)
    assert again is not None and again.reused and again.n_episodes == 2 and again.n_frames == first.n_frames
    assert reusable_export(root, REPO_ID, "another-key") is None
    # a demo file whose bytes changed gives a new key
    tampered = tmp_path / "tampered" / synthetic_paths[1].name
    tampered.parent.mkdir()
    raw = bytearray(synthetic_paths[1].read_bytes())
    raw[-1] ^= 1
    tampered.write_bytes(bytes(raw))
    assert export_key([synthetic_paths[0], tampered], labels, REPO_ID, 100, "v1") != key
    # a damaged dataset with a matching key is an error, not a silent reuse
    for f in (root / "data").glob("*/*.parquet"):
        f.write_bytes(b"not parquet")
    with pytest.raises(ExportError, match="unreadable"):
        reusable_export(root, REPO_ID, key)


def test_failed_validation_keeps_existing_dataset(tmp_path: Path, synthetic_paths: list[Path],
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from prl import export

    root = tmp_path / "ds"
    export_lerobot(synthetic_paths, root, repo_id=REPO_ID)
    before = _snapshot(root)
    seen = []

    def failing_validation(staging, repo_id, **kwargs):
        seen.append(Path(staging))
        assert (Path(staging) / "meta" / "info.json").is_file()  # written and finalized, not yet in place
        raise ExportError("simulated validation failure")

    monkeypatch.setattr(export, "validate_lerobot", failing_validation)
    with pytest.raises(ExportError, match="simulated"):
        export_lerobot(synthetic_paths[:1], root, repo_id=REPO_ID)
    assert seen and seen[0].parent == root.parent and seen[0] != root
    assert _snapshot(root) == before and _siblings(root) == []


def test_dataset_set_aside_by_a_killed_export_is_restored(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    root = tmp_path / "ds"
    export_lerobot(synthetic_paths, root, repo_id=REPO_ID)
    before = _snapshot(root)
    root.rename(root.parent / f".{root.name}.old-{_dead_pid()}")  # killed between the two renames
    corrupt = _truncated_copy(synthetic_paths[0], tmp_path / "corrupt.npz")
    with pytest.raises(ValueError, match="corrupt.npz"):
        export_lerobot([corrupt], root, repo_id=REPO_ID)
    assert _snapshot(root) == before and _siblings(root) == []


def test_video_spec_holds_each_picture_until_the_next() -> None:
    spec = VideoSpec(width=32, height=16, fps=10)
    assert spec.hold == 5  # 50 dataset frames a second, 10 pictures
    assert spec.records(12).tolist() == [0, 5, 10]
    pictures = np.stack([np.full((16, 32, 3), v, np.uint8) for v in (7, 8, 9)])
    held = spec.expand(pictures, 12)
    assert held.shape == (12, 16, 32, 3) and held[:, 0, 0, 0].tolist() == [7] * 5 + [8] * 5 + [9] * 2
    assert set(spec.features()) == {"observation.images.front", "observation.images.wrist"}
    assert spec.features()["observation.images.front"] == {"dtype": "video", "shape": (16, 32, 3),
                                                           "names": ["height", "width", "channels"]}
    with pytest.raises(ValueError, match="expected"):
        spec.expand(pictures[:2], 12)  # too few pictures for 12 frames
    with pytest.raises(ValueError, match=r"video fps must divide the dataset's 50 fps .* got 7"):
        VideoSpec(fps=7)
    with pytest.raises(ValueError, match="video width must be an even number of pixels in 16..4096, got 127"):
        VideoSpec(width=127)


def test_video_encoder_is_lerobots_default_or_a_fallback() -> None:
    from lerobot.configs.video import RGBEncoderConfig

    assert video_encoder().vcodec == RGBEncoderConfig.vcodec == "libsvtav1"  # lerobot's default works here
    assert video_encoder(("h264_videotoolbox", "h264")).vcodec == "h264"  # a macOS-only encoder is skipped
    with pytest.raises(ValueError, match="no video encoder works here; tried h264_videotoolbox: .*; nope: "):
        video_encoder(("h264_videotoolbox", "nope"))


def _painted(demo, records, source=""):
    """Camera pictures whose colour is the record index (x 10) and the camera: which picture a decoded frame is
    can be read back from its colour."""
    return {cam: np.stack([np.full((64, 64, 3), (10 * k % 250, 40 + 160 * c, 90), np.uint8) for k in records])
            for c, cam in enumerate(VIDEO_CAMERAS)}


def test_video_export_holds_pictures_and_records_its_codec(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    import json

    spec = VideoSpec(width=64, height=64, fps=10)
    with pytest.raises(ValueError, match="render_images is None"):
        export_lerobot(synthetic_paths, tmp_path / "none", video=spec)
    key = export_key(synthetic_paths, None, REPO_ID, 50, "v1", spec)
    assert key != export_key(synthetic_paths, None, REPO_ID, 50, "v1")
    assert key != export_key(synthetic_paths, None, REPO_ID, 50, "v1", VideoSpec(width=64, height=64, fps=25))
    root = tmp_path / "ds"
    report = export_lerobot(synthetic_paths, root, repo_id=REPO_ID, video=spec, render_images=_painted, key=key)
    assert report.video_codec == "av1" and report.n_frames == 40
    info = json.loads((root / "meta" / "info.json").read_text())
    for cam in VIDEO_CAMERAS:
        feature = info["features"][video_key(cam)]
        assert feature["dtype"] == "video" and feature["info"]["video.codec"] == "av1"
        assert feature["info"]["video.fps"] == info["fps"] == 50
    ds = _load_dataset(root)  # offline, from the files alone
    for e, start in ((0, 0), (1, 23)):
        for k in (0, 4, 5, 9, 10, 16):
            item = ds[start + k]
            front = item["observation.images.front"].numpy()
            assert front.shape == (3, 64, 64)
            shown = 5 * (k // 5)  # the picture of the last record at or before k that got one
            assert abs(front[0].mean() * 255 - 10 * shown) < 4, (e, k, front[0].mean() * 255)
            assert abs(item["observation.images.wrist"].numpy()[1].mean() * 255 - 200) < 4
    assert reusable_export(root, REPO_ID, key, spec).video_codec == "av1"


# ----------------------------------------------------------------------------- simulation tier


@pytest.fixture(scope="module")
def sim_demos(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three real demos (1/5 of the paper's episode length to keep it quick), successful or not."""
    pytest.importorskip("mani_skill")
    import envs  # noqa: F401
    from envs.execution import ExecutorConfig
    from envs.executor import PlanExecutor
    from envs.tasks import make_env
    from prl.demo import from_episode, save_demo
    from prl.plb import load_plb

    texts = load_plb().texts("hammer")
    out = tmp_path_factory.mktemp("sim_demos")
    env = make_env("hammer")
    try:
        executor = PlanExecutor(env, ExecutorConfig(n_frames=300))
        paths = []
        for k, (plan, seed) in enumerate((([0, 3, 2, 0, 0, 1], 3), ([1, 4, 2, 0, 0, 1], 4), ([0, 3, 1, 1, 0, 1], 5))):
            result = executor.run(plan, seed=seed)
            demo = from_episode("hammer", seed, texts[k % len(texts)], result, env)
            paths.append(save_demo(demo, out / f"ep{seed}.npz"))
    finally:
        env.close()
    return paths


@pytest.mark.sim
def test_export_reload_matches_demos(tmp_path: Path, sim_demos: list[Path]) -> None:
    from prl.demo import load_demo

    demos = [load_demo(p) for p in sim_demos]
    label = [5, 4, 3, 2, 1, 0]
    root = tmp_path / "lerobot" / "hammer"
    report = export_lerobot(sim_demos, root, repo_id=REPO_ID, per_episode_label={sim_demos[1]: label})
    assert report.root == root and report.n_labelled == 1
    assert _siblings(root) == []

    ds = _load_dataset(root)
    assert ds.num_episodes == len(demos) == 3
    lengths = [int(v) for v in ds.meta.episodes["length"]]
    assert lengths == [len(d.stage) for d in demos] == list(report.episode_lengths)
    assert len(ds) == sum(lengths) == report.n_frames
    assert [t[0] for t in ds.meta.episodes["tasks"]] == [d.text for d in demos]
    assert ds.fps == RECORD_HZ == 50 and ds.meta.info.codebase_version == "v3.0"

    starts = np.concatenate([[0], np.cumsum(lengths)])
    for e, demo in enumerate(demos):
        for k in (0, lengths[e] // 2, lengths[e] - 1):
            item = ds[int(starts[e]) + k]
            assert int(item["episode_index"]) == e and int(item["frame_index"]) == k
            np.testing.assert_allclose(item["observation.state"].numpy(),
                                       np.concatenate([demo.qpos[k], demo.qvel[k]]), rtol=1e-6, atol=1e-6)
            # the target to reach by the end of the step: the next record's (the last keeps its own)
            np.testing.assert_allclose(item["action"].numpy(), demo.target[min(k + 1, lengths[e] - 1)], rtol=1e-6,
                                       atol=1e-6)
            env_state = item["observation.environment_state"].numpy()
            np.testing.assert_allclose(env_state[:7], demo.tool_pose[k], rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(env_state[14], demo.scene_qpos[k, 0], rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(item["observation.contact_position"].numpy(),
                                       demo.contact_pos[k].reshape(-1), rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(item["observation.tool_pose"].numpy(), demo.tool_pose[k], rtol=1e-6, atol=1e-6)
            assert int(item["stage"]) == int(demo.stage[k])
            assert item["plan"].tolist() == demo.plan.tolist()
            assert item["label"].tolist() == (label if e == 1 else [NO_LABEL] * 6)
            np.testing.assert_array_equal(item["x_manip"].numpy(), demo.x_manip)
            assert item["task"] == demo.text

    again = validate_lerobot(root, REPO_ID)
    assert again.episode_lengths == report.episode_lengths and again.tasks == report.tasks


@pytest.mark.sim
def test_failed_export_leaves_good_dataset_untouched(tmp_path: Path, sim_demos: list[Path]) -> None:
    root = tmp_path / "hammer"
    export_lerobot(sim_demos, root, repo_id=REPO_ID)
    before = _snapshot(root)
    corrupt = _truncated_copy(sim_demos[0], tmp_path / "corrupt.npz")
    with pytest.raises(ValueError, match="corrupt.npz"):
        export_lerobot([sim_demos[1], corrupt], root, repo_id=REPO_ID)
    assert _snapshot(root) == before
    assert _siblings(root) == []
    assert validate_lerobot(root, REPO_ID).n_episodes == 3

    # a successful re-export replaces it as a whole
    report = export_lerobot(sim_demos[:2], root, repo_id=REPO_ID)
    assert report.n_episodes == 2 and _load_dataset(root).num_episodes == 2
    assert _siblings(root) == []


def test_export_cache_version_covers_the_export_sources_only() -> None:
    import hashlib

    from flows.export_dataset import EXPORT_SOURCES
    from prl.constants import REPO_ROOT
    from prl.version import source_version

    expected = hashlib.sha256()
    for rel in EXPORT_SOURCES:
        expected.update(rel.encode())
        expected.update((REPO_ROOT / rel).read_bytes())
    assert source_version(*EXPORT_SOURCES) == expected.hexdigest()[:16]
    assert "prl/rn.py" not in EXPORT_SOURCES  # RN work does not invalidate the dataset
    with pytest.raises(FileNotFoundError, match="'prl/nope.py'"):
        source_version("prl/nope.py")


def _hand_away(demo, k: int, spec: VideoSpec) -> dict[str, np.ndarray]:
    """The pictures of record ``k`` with the hand lifted 2 m out of the scene (everything else as recorded)."""
    from envs.scene_record import SceneParts
    from envs.tasks import make_env
    from envs.video import add_video_cameras, pictures, set_recorded_state
    from prl.constants import JOINT_NAMES

    env = make_env(demo.task)
    try:
        env.reset(seed=demo.seed)
        cameras = add_video_cameras(env, spec.width, spec.height)
        moved = demo.qpos.copy()
        moved[k, JOINT_NAMES.index("ARTz")] += 2.0
        demo.arrays["qpos"] = moved
        set_recorded_state(env, SceneParts(env), demo, k)
        return pictures(env, cameras)
    finally:
        env.close()


@pytest.mark.sim
def test_video_of_simulated_demos_decodes_and_shows_the_scene(tmp_path: Path, sim_demos: list[Path]) -> None:
    """Two real demos exported with the cameras' video, reloaded offline: the decoded frames are the rendered
    scene (not black, changing over the episode) with the hand in it (it covers pixels that a render of the
    same instant without the hand does not)."""
    from envs.video import DemoRenderer
    from prl.demo import load_demo

    spec = VideoSpec(width=96, height=96, fps=10)
    root = tmp_path / "video"
    with DemoRenderer(spec) as render:
        report = export_lerobot(sim_demos[:2], root, repo_id=REPO_ID, video=spec, render_images=render)
    assert report.video_codec == "av1" and report.video_seconds > 0
    assert sorted(p.parent.parent.name for p in (root / "videos").rglob("*.mp4")) == \
        ["observation.images.front", "observation.images.wrist"]
    ds = _load_dataset(root)
    demo = load_demo(sim_demos[0])
    t = len(demo.stage)
    frames = {k: {cam: (ds[k][video_key(cam)].numpy().transpose(1, 2, 0) * 255) for cam in VIDEO_CAMERAS}
              for k in (0, t // 2, t - 1)}
    for k, shot in frames.items():
        for cam, image in shot.items():
            assert image.mean() > 30 and image.std() > 10, (k, cam)  # a lit scene with structure, not black
    for cam in VIDEO_CAMERAS:  # the episode moves: the hand carries the hammer away from the rack
        assert np.abs(frames[t - 1][cam] - frames[0][cam]).mean() > 3, cam
    k = t // 2
    away = _hand_away(demo, 5 * (k // 5), spec)["front"].astype(float)
    hand = np.abs(frames[k]["front"] - away).max(axis=-1) > 40
    assert hand.mean() > 0.01, hand.mean()  # the hand (and the hammer it holds) covers > 1% of the front view


@pytest.mark.integration
def test_lerobot_visualiser_saves_an_episode(tmp_path: Path, synthetic_paths: list[Path]) -> None:
    """lerobot's own viewer (``lerobot-dataset-viz``, with ``lerobot[viz]``) reads an exported episode with video
    and writes its Rerun recording, as the README shows."""
    pytest.importorskip("rerun")
    root = tmp_path / "ds"
    export_lerobot(synthetic_paths, root, repo_id=REPO_ID, video=VideoSpec(width=64, height=64),
                   render_images=_painted)
    viz = Path(sys.executable).with_name("lerobot-dataset-viz")
    res = subprocess.run([str(viz), "--repo-id", REPO_ID, "--root", str(root), "--episode-index", "1",
                          "--save", "1", "--output-dir", str(tmp_path / "rrd"), "--num-workers", "0"],
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    rrd = tmp_path / "rrd" / f"{REPO_ID.replace('/', '_')}_episode_1.rrd"
    assert rrd.stat().st_size > 10_000
