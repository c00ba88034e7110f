"""The real sample (UTM-sized coordinates) through the wgpu backend: same image as the CPU."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint
from gigapoint import Camera, RenderSettings
from gigapoint.errors import BackendUnavailableError

pytestmark = pytest.mark.gpu


@pytest.mark.parametrize("view", ["iso", "top"])
def test_autzen_wgpu_image_equals_cpu(autzen_path, view):
    cloud = gigapoint.open(autzen_path)
    cam = Camera.fit(cloud.bounds, view=view, width=400, height=300)
    try:
        gpu = gigapoint.render_frame(cloud, cam, RenderSettings(backend="wgpu", size_mode="fixed"))  # the exact one-pixel render
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    cpu = gigapoint.render_frame(cloud, cam, RenderSettings(backend="cpu", size_mode="fixed"))
    differ = int(np.count_nonzero(gpu.visibility != cpu.visibility))
    assert differ <= 0.001 * cpu.visibility.size
    assert gpu.stats.visible_pixels > 5_000
    assert np.count_nonzero(np.any(gpu.image != cpu.image, axis=-1)) <= differ
