"""Color modes (issue #5): every mode against a plain-numpy recomputation from the winning indices."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import SettingsError
from gigapoint.render.colors import classification_table, colormap_table, elevations, point_colors
from gigapoint.render.passes.lighting import point_normals


@pytest.fixture(scope="module")
def scene():
    xyz, rgba, attrs = gp.demo_arrays(60_000, seed=3)
    rng = np.random.default_rng(0)
    attrs["return_number"] = rng.integers(1, 5, len(xyz)).astype(np.uint8)
    attrs["point_source_id"] = rng.integers(0, 7, len(xyz)).astype(np.uint16)
    n = rng.normal(size=(len(xyz), 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    attrs.update(nx=n[:, 0], ny=n[:, 1], nz=n[:, 2])
    cloud = gp.from_arrays(xyz, rgba, name="colors", **attrs)
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 50.0), width=160, height=100)
    return cloud, cam


def _pixels(frame):
    idx = frame.index.reshape(-1)
    return idx, idx >= 0


def _check(frame, expected_rgba_per_point, background=(0, 0, 0, 255)):
    idx, hit = _pixels(frame)
    img = frame.image.reshape(-1, 4)
    assert hit.sum() > 1000
    np.testing.assert_array_equal(img[hit], expected_rgba_per_point[idx[hit]])
    np.testing.assert_array_equal(img[~hit], np.broadcast_to(np.array(background, np.uint8), img[~hit].shape))


def test_rgb_is_the_clouds_color(scene):
    cloud, cam = scene
    _check(gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu")), cloud.rgba)


def test_classification_uses_the_asprs_table(scene):
    cloud, cam = scene
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="classification"))
    expected = classification_table()[cloud.attributes["classification"].astype(np.int64)]
    _check(f, expected)
    assert tuple(classification_table()[2, :3]) == (160, 82, 45)  # ground is brown
    assert tuple(classification_table()[9, :3]) == (0, 0, 255)  # water is blue


def test_intensity_with_contrast_range(scene):
    cloud, cam = scene
    lo, hi = 15000.0, 40000.0
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="intensity", intensity_range=(lo, hi)))
    v = cloud.attributes["intensity"].astype(np.float64)
    g = np.clip(np.rint((v - lo) * 255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    expected = np.stack([g, g, g, np.full_like(g, 255)], axis=1)
    _check(f, expected)


@pytest.mark.parametrize("cmap", ["viridis", "turbo"])
def test_any_attribute_through_the_colormap(scene, cmap):
    """color_mode 'attribute' maps ``color_attribute`` (any the cloud holds: here a normal's
    component) through the colormap over ``attribute_range``, or its 2nd..98th percentile;
    naming none, or one the cloud lacks, is a one-line error listing what it has."""
    cloud, cam = scene
    v = cloud.attributes["nz"].astype(np.float64)
    for rng in ((-0.5, 0.8), None):
        f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="attribute", color_attribute="nz", colormap=cmap, attribute_range=rng))
        lo, hi = rng or np.percentile(v, [2.0, 98.0])
        i = np.clip(np.rint((v - lo) * 255.0 / (hi - lo)), 0, 255).astype(np.int64)
        _check(f, colormap_table(cmap)[i])
    with pytest.raises(SettingsError, match="^color_mode 'attribute': name the attribute with color_attribute .*colors has: classification, intensity"):
        gp.render(cloud, cam, color_mode="attribute")
    with pytest.raises(SettingsError, match="^color_attribute: colors has no attribute 'height' \\(attributes: classification"):
        gp.render(cloud, cam, color_mode="attribute", color_attribute="height")


@pytest.mark.parametrize("cmap", ["viridis", "turbo", "terrain", "inferno", "gray"])
def test_elevation_colormaps(scene, cmap):
    cloud, cam = scene
    zr = (-5.0, 30.0)
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="elevation", colormap=cmap, elevation_range=zr))
    z = cloud.positions()[:, 2]  # the library's own float64 dequantization, independent of the kernel
    i = np.clip(np.rint((z - zr[0]) * 255.0 / (zr[1] - zr[0])), 0, 255).astype(np.int64)
    _check(f, colormap_table(cmap)[i])


def test_elevations_match_positions(scene):
    cloud, _ = scene
    np.testing.assert_array_equal(elevations(cloud), cloud.positions()[:, 2])
    assert elevations(cloud) is elevations(cloud)  # cached on the cloud


def test_a_new_color_mode_keeps_the_other_derived_arrays(scene):
    """The RenderCache keeps one color array at a time, and the elevations and normals beside it."""
    cloud, _ = scene
    z, normals = elevations(cloud), point_normals(cloud)
    first = point_colors(cloud, gp.RenderSettings(color_mode="intensity"))
    point_colors(cloud, gp.RenderSettings(color_mode="classification"))
    assert elevations(cloud) is z and point_normals(cloud) is normals
    assert point_colors(cloud, gp.RenderSettings(color_mode="intensity")) is not first  # dropped, computed again


def test_colormap_tables_have_the_published_end_points():
    v = colormap_table("viridis")
    assert tuple(v[0, :3]) == (68, 1, 84) and tuple(v[-1, :3]) == (253, 231, 37)
    t = colormap_table("turbo")
    assert t[64, 2] > t[64, 0] and t[128, 1] > max(t[128, 0], t[128, 2]) and t[-1, 0] > t[-1, 2]  # blue, green, red
    assert tuple(colormap_table("terrain")[-1, :3]) == (255, 255, 255)  # snow caps
    g = colormap_table("gray")
    np.testing.assert_array_equal(g[:, 0], np.arange(256))


def test_return_number_point_source_batch_level_normal(scene):
    cloud, cam = scene
    for mode in ("return_number", "point_source_id", "batch", "level", "normal"):
        s = gp.RenderSettings(backend="cpu", color_mode=mode)
        f = gp.render_frame(cloud, cam, s)
        _check(f, point_colors(cloud, s).view(np.uint8).reshape(-1, 4))
    # return numbers: equal numbers equal colors, different numbers different colors
    pc = point_colors(cloud, gp.RenderSettings(color_mode="return_number"))
    rn = cloud.attributes["return_number"]
    for r in range(1, 5):
        assert len(np.unique(pc[rn == r])) == 1
    assert len(np.unique(pc)) == 4
    # batches: one color per batch, neighbours differ
    pb = point_colors(cloud, gp.RenderSettings(color_mode="batch"))
    b = cloud.batch_of(np.arange(cloud.n_points))
    assert all(len(np.unique(pb[b == k])) == 1 for k in range(len(cloud.batches)))
    assert len(np.unique(pb)) == len(cloud.batches)
    # normals: (n * 0.5 + 0.5) * 255
    pn = point_colors(cloud, gp.RenderSettings(color_mode="normal")).view(np.uint8).reshape(-1, 4)
    n = np.stack([cloud.attributes[k] for k in ("nx", "ny", "nz")], axis=1)
    np.testing.assert_array_equal(pn[:, :3], np.clip(np.rint((n * 0.5 + 0.5) * 255), 0, 255).astype(np.uint8))


def test_missing_attribute_and_bad_settings_are_one_line_errors():
    cloud = gp.from_arrays(np.random.default_rng(1).random((500, 3)), name="bare")
    cam = gp.Camera.fit(cloud.bounds, width=32, height=32)
    with pytest.raises(SettingsError, match="bare has no intensity attribute"):
        gp.render(cloud, cam, color_mode="intensity")
    with pytest.raises(SettingsError, match="no normals"):
        gp.render(cloud, cam, color_mode="normal")
    bad_settings = (
        {"color_mode": "height"},
        {"colormap": "jet"},
        {"elevation_range": (5, 1)},
        {"intensity_range": "x"},
        {"fill_holes": 4},
        {"point_size": 0},
        {"point_shape": "star"},
        {"size_mode": "attenuated"},  # needs point_world_size
        {"supersample": 3},
        {"supersample_filter": "bicubic"},
        {"stereo": "vr"},
        {"splat_softness": 1.0},  # needs hqs
        {"edl_strength": float("nan")},
        {"edl_strength": 1e39},  # inf as the kernels' float32: garbage colours on the CPU, black on the GPU
        {"hqs_depth_tolerance": -0.1},
    )
    for bad in bad_settings:
        with pytest.raises(SettingsError) as err:
            gp.RenderSettings(**bad)
        assert "\n" not in str(err.value) and next(iter(bad)).split("_")[0] in str(err.value)


def test_nan_attribute_values_are_grey_and_the_rest_keep_the_range():
    """An attribute with NaN (no value) colours those points grey and maps the others over the
    finite values' 2nd..98th percentile; was numpy's IndexError (NaN cast to an index). All NaN: all grey."""
    n = 4000
    rng = np.random.default_rng(2)
    v = rng.random(n) * 10.0
    v[::4] = np.nan
    cloud = gp.from_arrays(np.c_[rng.random((n, 2)) * 10.0, np.zeros(n)], name="gaps", h=v, none=np.full(n, np.nan))
    cam = gp.Camera.fit(cloud.bounds, view="top", width=80, height=80)
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="attribute", color_attribute="h", colormap="viridis"))
    v = cloud.attributes["h"].astype(np.float64)  # in the cloud's (Morton) order, as frame.index counts
    lo, hi = np.nanpercentile(v, [2.0, 98.0])
    expected = colormap_table("viridis")[np.clip(np.rint((np.nan_to_num(v) - lo) * 255.0 / (hi - lo)), 0, 255).astype(np.int64)]
    expected[np.isnan(v)] = (128, 128, 128, 255)
    _check(f, expected)
    assert np.isnan(v[f.index[f.index >= 0]]).any()  # some grey points are in view
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", color_mode="attribute", color_attribute="none"))
    hit = f.index >= 0
    assert hit.sum() > 1000 and (f.image[hit] == (128, 128, 128, 255)).all()


def test_an_attribute_of_several_values_a_point_is_a_one_line_error():
    """color_attribute='normal' of an NPZ's (N, 3) normals was numba's many-line TypingError."""
    rng = np.random.default_rng(3)
    cloud = gp.from_arrays(rng.random((800, 3)), name="npz", normal=rng.random((800, 3)).astype(np.float32))
    cam = gp.Camera.fit(cloud.bounds, width=32, height=24)
    with pytest.raises(SettingsError) as err:
        gp.render(cloud, cam, color_mode="attribute", color_attribute="normal")
    assert str(err.value) == "color_attribute: 'normal' of npz holds 3 values a point; colour by an attribute of one value a point (normals: color_mode 'normal')"
    assert (gp.render(cloud, cam, color_mode="normal", size_mode="fixed")[..., :3] != 0).any()  # those normals colour by color_mode 'normal'
