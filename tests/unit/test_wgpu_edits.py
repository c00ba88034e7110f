"""A cloud the program changes between renders, on the wgpu backend: after ``set_colors`` or
``changed()`` the GPU's copies are refreshed and it draws the CPU's pixels (lavapipe: exactly)."""

from __future__ import annotations

import numpy as np
import pytest
from test_cloud_edits import BLUE, FORMATS, blue_where_west, edit_scene, pixel_colors
from wgpu_support import gpu  # noqa: F401 - fixture

import gigapoint as gp

pytestmark = pytest.mark.gpu


def both(cloud, cam, settings):
    """(CPU image, wgpu image) of one frame."""
    return gp.render(cloud, cam, settings), gp.render(cloud, cam, settings.replace(backend="wgpu"))


@pytest.mark.parametrize("kw", FORMATS, ids=lambda kw: kw["colors"])
def test_set_colors_draws_the_cpus_pixels(gpu, kw):
    cloud, cam, settings = edit_scene(**kw)
    cpu, wgpu = both(cloud, cam, settings)  # the colours are on the GPU now
    np.testing.assert_array_equal(wgpu, cpu)
    blue_where_west(cloud)
    cpu, wgpu = both(cloud, cam, settings)
    assert (cpu == BLUE).all(axis=-1).sum() > 1000
    np.testing.assert_array_equal(wgpu, cpu)


def test_rgba_view_written_then_changed_draws_the_cpus_pixels(gpu):
    cloud, cam, settings = edit_scene(colors="rgba")
    both(cloud, cam, settings)
    some = np.flatnonzero(cloud.positions()[:, 1] < 3)
    cloud.rgba[some] = BLUE
    cloud.changed(some)  # only their batches go to the GPU again
    cpu, wgpu = both(cloud, cam, settings)
    assert BLUE in pixel_colors(cpu)
    np.testing.assert_array_equal(wgpu, cpu)


def test_attribute_replaced_then_changed_draws_the_cpus_pixels(gpu):
    cloud, cam, settings = edit_scene(scale=0.001)
    by_attribute = settings.replace(color_mode="attribute", color_attribute="intensity", colormap="gray", attribute_range=(0.0, 999.0))
    before, _ = both(cloud, cam, by_attribute)
    cloud.attributes["intensity"] = np.where(cloud.positions()[:, 0] < 5, 0, 999).astype(np.uint16)
    cloud.changed()
    cpu, wgpu = both(cloud, cam, by_attribute)
    assert (cpu == 255).all(axis=-1).sum() > 1000 and not np.array_equal(cpu, before)
    np.testing.assert_array_equal(wgpu, cpu)
