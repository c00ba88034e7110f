"""A cloud the program changes between renders (colours, attributes): drawn with the new values."""

from __future__ import annotations

import re

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError, PointIndexError

FORMATS = [{"colors": "rgba"}, {"scale": 0.001, "colors": "rgb565"}, {"scale": 0.001, "colors": "palette"}]
BLUE, BLACK = (0, 0, 255, 255), (0, 0, 0, 255)


def edit_scene(**kw):
    """20 000 grey points on a 10 m square (a mm grid), a camera above it, fixed-size splats."""
    rng = np.random.default_rng(0)
    xyz = np.round(rng.uniform(0, 10, (20_000, 3)) * [1, 1, 0.1], 3)
    cloud = gp.from_arrays(xyz, np.full((len(xyz), 3), 200, np.uint8), intensity=rng.integers(0, 1000, len(xyz)).astype(np.uint16), **kw)
    cam = gp.Camera.fit(cloud.bounds, view="top", width=120, height=90)
    return cloud, cam, gp.RenderSettings(size_mode="fixed", backend="cpu")


def blue_where_west(cloud):
    """The point indices west of x = 5, set blue; returns them."""
    west = np.flatnonzero(cloud.positions()[:, 0] < 5)
    cloud.set_colors(BLUE[:3], west)
    return west


def pixel_colors(image) -> set:
    return {tuple(c) for c in np.unique(image.reshape(-1, 4), axis=0).tolist()}


@pytest.mark.parametrize("kw", FORMATS, ids=lambda kw: kw["colors"])
def test_set_colors_reads_back_and_draws_in_every_colour_format(kw):
    cloud, cam, settings = edit_scene(**kw)
    grey = tuple(cloud.rgba[0].tolist())  # (198, 199, 198) in RGB565
    assert grey[:3] in ((200, 200, 200), (198, 199, 198)) and pixel_colors(gp.render(cloud, cam, settings)) == {grey, BLACK}
    west = blue_where_west(cloud)
    assert 9_000 < len(west) < 11_000
    assert (cloud.rgba[west] == BLUE).all() and (cloud.rgba[np.setdiff1d(np.arange(cloud.n_points), west)] == grey).all()
    after = gp.render(cloud, cam, settings)
    x = np.arange(cam.width)
    covered = after[..., :3].any(axis=-1)  # not the black background
    assert (after[:, x < 50][covered[:, x < 50]] == BLUE).all()  # the west half of the image: blue only
    assert (after[:, x > 70][covered[:, x > 70]] == grey).all()
    assert cloud.version == 1 and set(np.flatnonzero(cloud.batch_version).tolist()) == set(np.unique(cloud.batch_of(west)).tolist())


def test_set_colors_takes_one_colour_for_all_and_floats():
    cloud, cam, settings = edit_scene()
    cloud.set_colors([0.0, 0.0, 1.0])  # floats of 0..1, as from_arrays judges them
    assert pixel_colors(gp.render(cloud, cam, settings)) == {BLUE, BLACK}
    assert cloud.batch_version.tolist() == [1] * len(cloud.batches)


def test_set_colors_refuses_bad_colours_and_indices_in_one_line():
    cloud, _, _ = edit_scene(scale=0.001, colors="rgb565")
    with pytest.raises(InputError, match=r"^arrays: set_colors: 2 colours for 3 points$"):
        cloud.set_colors(np.zeros((2, 3), np.uint8), [0, 1, 2])
    with pytest.raises(InputError, match=r"^arrays: set_colors: 16-bit colors drop alpha, and some given are not opaque$"):
        cloud.set_colors([10, 20, 30, 128], [5])
    with pytest.raises(PointIndexError, match=r"^arrays: point index 20000 out of range 0..19999$"):
        cloud.set_colors([1, 2, 3], [20_000])
    with pytest.raises(PointIndexError, match=r"^arrays: point indices must be whole numbers, got float64$"):
        cloud.changed([1.5])
    assert cloud.version is None  # nothing was changed


def test_changed_after_writing_the_rgba_view_recolours_hqs_and_colour_modes():
    """``rgba`` of 32-bit colours is a view: written, then ``changed()``, every cache draws it."""
    cloud, cam, settings = edit_scene(colors="rgba")
    hqs = settings.replace(hqs=True)
    assert BLUE not in pixel_colors(gp.render(cloud, cam, hqs))
    cloud.rgba[:] = BLUE
    cloud.changed()
    assert pixel_colors(gp.render(cloud, cam, hqs)) <= {BLUE, BLACK}


def test_changed_after_replacing_an_attribute_recolours_its_colour_mode():
    cloud, cam, settings = edit_scene()
    by_attribute = settings.replace(color_mode="attribute", color_attribute="intensity", colormap="gray", attribute_range=(0.0, 999.0))
    assert len(pixel_colors(gp.render(cloud, cam, by_attribute))) > 100  # random intensities: many greys
    cloud.attributes["intensity"] = np.where(cloud.positions()[:, 0] < 5, 0, 999).astype(np.uint16)
    cloud.changed()
    after = gp.render(cloud, cam, by_attribute)
    assert pixel_colors(after) == {BLACK, (255, 255, 255, 255)}  # (black: the background too)


@pytest.mark.parametrize(
    "values, problem",
    [
        (np.zeros(5, np.uint16), "attribute 'bad' has 5 rows for 20,000 points"),  # the CPU drew colours read past them, the GPU black
        ([1, 2, 3], "attribute 'bad' has 3 rows for 20,000 points"),
        (np.array(["a"] * 20_000), "attribute 'bad' has dtype <U1: attributes are numbers (bool, integers, floats of at most 64 bits)"),
        (7, "attribute 'bad' is one value (7), not one per point"),
    ],
)
def test_an_attribute_the_program_adds_is_checked_as_from_arrays_checks_it(values, problem):
    cloud, _, _ = edit_scene()
    with pytest.raises(InputError, match=rf"^arrays: {re.escape(problem)}$"):
        cloud.attributes["bad"] = values
    assert "bad" not in cloud.attributes
    with pytest.raises(InputError, match=r"^arrays: attribute name 'a/b' cannot be stored"):
        cloud.attributes["a/b"] = np.zeros(cloud.n_points)
    cloud.attributes["good"] = np.arange(cloud.n_points, dtype=np.float32)  # one a point: held (packed)
    assert cloud.point_info(7)["good"] == 7.0 and cloud.attributes.held_dtype("good") == "float32"


@pytest.mark.parametrize("kw", FORMATS[1:], ids=lambda kw: kw["colors"])
def test_rgba_of_16_bit_colours_or_palettes_is_a_read_only_copy(kw):
    cloud, _, _ = edit_scene(**kw)
    with pytest.raises(ValueError, match="read-only"):  # (written, it changed nothing, without a word)
        cloud.rgba[0] = BLUE
    cloud.set_colors([BLUE], [0])
    assert cloud.rgba[0].tolist() == list(BLUE)
