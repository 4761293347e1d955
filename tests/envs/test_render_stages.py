"""Stage pictures: one non-blank PNG per executor stage (plus the initial scene) and a contact sheet."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mani_skill")

from envs import render_probe
from prl.stages import STAGES

EXPERT = [0, 3, 2, 0, 0, 1]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    report = render_probe.probe()
    if not report.rendering:
        pytest.skip(f"no working renderer: {report.error or 'no Vulkan device'} (see python -m envs.render_probe)")
    from envs.render_stages import render_stages

    out = tmp_path_factory.mktemp("stages")
    return out, render_stages("hammer", EXPERT, 0, out)


def _load(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


@pytest.mark.sim
def test_stage_pictures_written(rendered):
    from envs.render_stages import IMAGE_SIZE

    out, paths = rendered
    names = [p.name for p in paths]
    from envs.tasks import task_class

    ran = [name for name, _ in task_class("hammer").stages.shares]  # the stages the task declares, in order
    assert set(ran) < set(STAGES)
    assert names == ["00_initial.png"] + [f"{i + 1:02d}_{s}.png" for i, s in enumerate(ran)] + ["stages.png"]
    assert len(list(out.glob("0*.png"))) == len(ran) + 1
    for path in paths[:-1]:
        image = _load(path)
        assert image.shape == (IMAGE_SIZE[1], IMAGE_SIZE[0], 3), path
        assert image.astype(np.float64).std() > 10.0, f"{path.name} looks blank"
    sheet = _load(paths[-1])
    assert sheet.shape[0] > IMAGE_SIZE[1] and sheet.shape[1] > IMAGE_SIZE[0]
    assert sheet.astype(np.float64).std() > 10.0


@pytest.mark.sim
def test_stage_pictures_show_the_motion(rendered):
    out, _ = rendered
    pregrasp = _load(out / "01_pregrasp.png").astype(np.float64)
    motion = _load(out / "07_motion.png").astype(np.float64)
    changed = np.abs(pregrasp - motion).max(axis=-1) > 30.0
    assert changed.mean() > 0.02, f"only {changed.mean():.3%} of the pixels changed between pregrasp and motion"


def test_render_stages_refuses_without_renderer(monkeypatch, tmp_path):
    from envs import render_stages as module

    fake = render_probe.ProbeReport(sapien="3.0.3", mesa_vulkan_drivers="", device="", rendering=False,
                                    error="failed to find a rendering device")
    monkeypatch.setattr(render_probe, "probe", lambda: fake)
    with pytest.raises(render_probe.RenderingUnavailable, match="stage pictures"):
        module.render_stages("hammer", EXPERT, 0, tmp_path)
    assert not list(tmp_path.iterdir())
