"""The rendering probe reports honestly and refuses loudly."""

from __future__ import annotations

import pytest

from envs import render_probe


def test_require_rendering_raises_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = render_probe.ProbeReport(sapien="3.0.3", mesa_vulkan_drivers="22.3.6-1", device="",
                                    rendering=False, error="failed to find a rendering device")
    monkeypatch.setattr(render_probe, "probe", lambda: fake)
    with pytest.raises(render_probe.RenderingUnavailable, match="failed to find a rendering device.*22.3.6-1"):
        render_probe.require_rendering("dataset video")


def test_probe_renders_when_lavapipe_installed() -> None:
    version = render_probe.mesa_version()
    if not version:
        pytest.skip("mesa-vulkan-drivers is not installed through dpkg on this machine")
    report = render_probe.probe()
    major_minor = tuple(int(p) for p in version.split(".")[:2])
    assert report.sapien == "3.0.3"
    # set-up installs Mesa >= 24.3, which SAPIEN 3.0.3 is known to render with
    assert report.rendering == (major_minor >= (24, 3)), report
