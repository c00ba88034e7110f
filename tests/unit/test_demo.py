import numpy as np

from gigapoint.io.demo import demo_arrays, demo_chunks


def test_demo_is_deterministic_and_sliceable():
    a_xyz, a_rgba, a_attr = demo_arrays(50_000, seed=3)
    b_xyz, b_rgba, _ = demo_arrays(20_000, seed=3, start=30_000)
    np.testing.assert_array_equal(a_xyz[30_000:], b_xyz)
    np.testing.assert_array_equal(a_rgba[30_000:], b_rgba)
    chunks = list(demo_chunks(50_000, seed=3, chunk_size=7_000))
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in chunks]), a_xyz)
    assert set(a_attr) == {"classification", "intensity"}


def test_demo_has_terrain_buildings_and_trees():
    xyz, rgba, attrs = demo_arrays(100_000)
    assert np.isfinite(xyz).all()
    assert xyz[:, :2].min() >= -10 and xyz[:, :2].max() <= 1010  # tree crowns may overhang the border
    classes, counts = np.unique(attrs["classification"], return_counts=True)
    share = dict(zip(classes.tolist(), (counts / counts.sum()).tolist()))
    assert share[2] > 0.2 and share[6] > 0.15 and share[5] > 0.1  # ground, buildings, vegetation
    assert {9, 11} <= set(share)  # water and roads
    assert xyz[attrs["classification"] == 6, 2].max() > 30  # tall buildings exist
    assert (rgba[:, 3] == 255).all()


def test_each_kind_stores_its_own_intensity_band():
    """Terrain (ground, water, roads) 20000..40000, buildings 30000..45000, trees 8000..20000 (the
    three kinds' stores share ``_store_point``: each passes its own class and intensity)."""
    _, _, attrs = demo_arrays(100_000)
    bands = {2: (20_000, 40_000), 9: (20_000, 40_000), 11: (20_000, 40_000), 6: (30_000, 45_000), 5: (8_000, 20_000)}
    for cls, (lo, hi) in bands.items():
        intensity = attrs["intensity"][attrs["classification"] == cls]
        assert intensity.size > 1000 and lo <= intensity.min() and intensity.max() < hi, cls
    assert set(np.unique(attrs["classification"]).tolist()) == set(bands)


def test_seed_changes_the_scene():
    a, _, _ = demo_arrays(1000, seed=1)
    b, _, _ = demo_arrays(1000, seed=2)
    assert not np.array_equal(a, b)


def test_mod_is_pythons_modulo_at_the_boundaries():
    """The generator's fmod-free ``_mod`` equals Python's ``a % m`` for a >= 0, also one to three
    ulps either side of every multiple (where the quotient rounds to the next integer)."""
    from numba import njit

    from gigapoint.io.demo import _mod

    mod = njit(lambda a, m: _mod(a, m))
    rng = np.random.default_rng(0)
    for m in (100.0, 4.0, 3.5):
        values = list(rng.random(20_000) * 1000.0)
        for k in range(300):
            v_lo = v_hi = k * m
            for _ in range(3):
                v_lo, v_hi = np.nextafter(v_lo, -np.inf), np.nextafter(v_hi, np.inf)
                values += [v for v in (v_lo, v_hi) if v >= 0]
        got = [mod(v, m) for v in values]
        assert got == [v % m for v in values]


def test_prefault_writes_one_byte_a_page_and_nothing_else():
    """``_prefault`` (run on the new output arrays before generating) zeroes the first byte of
    each 4 KiB page, including a last partial page, and leaves every other byte alone."""
    from gigapoint.io.demo import _prefault

    buffer = np.full(3 * 4096 + 100, 7, np.uint8)
    _prefault(buffer)
    pages = np.arange(0, buffer.size, 4096)
    assert (buffer[pages] == 0).all() and pages.size == 4
    rest = np.delete(buffer, pages)
    assert (rest == 7).all()
    _prefault(np.empty(0, np.uint8))  # an empty cloud's arrays
    xyz, _, _ = demo_arrays(0)
    assert xyz.shape == (0, 3)


def test_gp_demo_holds_the_town_at_1_cm_by_default():
    """gp.demo quantizes to a 1 cm grid (as a LAS export of the town would) and holds it in the
    compact layout (under 7 bytes a point of position and colour from ~10⁵ points on: the
    sparser the town, the wider its batches), every point exact at that grid; scale=None keeps
    the float positions."""
    import gigapoint as gp
    from gigapoint.io.demo import demo_arrays

    cloud = gp.demo(200_000)
    assert cloud.layout == "compact"
    mem = cloud.memory()
    assert (mem["positions"] + mem["color"]) / cloud.n_points <= 7.0
    xyz, _, _ = demo_arrays(200_000)
    want = np.sort(np.round(xyz / 0.01).astype(np.int64).view("i8,i8,i8").reshape(-1))
    got = np.sort(np.round(cloud.positions() / 0.01).astype(np.int64).view("i8,i8,i8").reshape(-1))
    np.testing.assert_array_equal(got, want)
    assert np.abs(cloud.positions() / 0.01 - np.round(cloud.positions() / 0.01)).max() < 1e-3
    assert gp.demo(30_000, scale=None).layout == "words"


def test_gp_demo_refuses_options_it_would_drop():
    """memory_limit= without progressive=True, and colors=/scale=/chunked=/attributes= with it,
    were dropped without a word (gp.open refuses the same)."""
    import pytest

    import gigapoint as gp
    from gigapoint.errors import InputError

    with pytest.raises(InputError, match=r"^demo: memory_limit= goes with progressive=True"):
        gp.demo(1000, memory_limit="1G")
    for kw, named in (({"colors": "rgba"}, "colors"), ({"scale": None, "attributes": False}, "scale, attributes"), ({"chunked": True}, "chunked")):
        with pytest.raises(InputError, match=f"^demo\\(progressive=True\\) takes memory_limit= only, not {named}$"):
            gp.demo(1000, progressive=True, **kw)
