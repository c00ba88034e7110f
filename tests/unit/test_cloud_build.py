"""The compiled point scan and gather used by build_cloud, against numpy."""

import re

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core import cloud
from gigapoint.core.cloud import MAX_ABS_COORDINATE, _valid_mask, gather, scan_points
from gigapoint.errors import InputError


@pytest.fixture(autouse=True, params=["numpy below the threshold", "the compiled kernels"])
def kernel_path(request, monkeypatch):
    """Both paths against numpy: small inputs take numpy's, large ones the parallel kernels."""
    if not request.param.startswith("numpy"):
        monkeypatch.setattr(cloud, "NUMPY_MAX", 0)


@pytest.mark.parametrize("n", [0, 1, 5, 1000, 100_003])
def test_scan_points_equals_numpy(rng, n):
    xyz = rng.normal(0, 1e5, (n, 3)) + 6e6
    if n > 4:
        xyz[rng.integers(0, n, max(1, n // 50)), rng.integers(0, 3, max(1, n // 50))] = np.nan
        xyz[1, 2] = np.inf
        xyz[2, 0] = -1e300
        xyz[3, 1] = MAX_ABS_COORDINATE  # the limit itself is valid
    bad, lo, hi = scan_points(xyz)
    valid = _valid_mask(xyz)
    assert bad == int((~valid).sum())
    if valid.any():
        np.testing.assert_array_equal(lo, xyz[valid].min(axis=0))
        np.testing.assert_array_equal(hi, xyz[valid].max(axis=0))
    else:
        assert np.all(lo == np.inf) and np.all(hi == -np.inf)


def test_gather_equals_fancy_indexing(rng):
    order = rng.permutation(50_000)
    for dtype in (np.uint8, np.uint16, np.uint32, np.float32, np.float64):
        values = rng.integers(0, 200, 50_000).astype(dtype)
        np.testing.assert_array_equal(gather(values, order), values[order])
    two_d = rng.normal(size=(50_000, 3))
    np.testing.assert_array_equal(gather(two_d, order), two_d[order])


def test_chunks_are_joined_with_numpys_dtype_for_them(monkeypatch):
    """build_cloud joins its chunks' arrays into one (in small pages where asked, core/pages.py):
    the same values and the dtype numpy's concatenate gives them (an attribute u8 in one file and
    u16 in the next becomes u16), and every point drawn from its chunk."""
    from gigapoint.core import build_cloud, pages
    from gigapoint.core.chunk import PointChunk

    monkeypatch.setenv("GIGAPOINT_SMALL_PAGES", "1")
    pages._madvise.cache_clear()
    try:
        rng = np.random.default_rng(4)
        parts = [
            PointChunk(rng.uniform(0, 100, (700_000, 3)), rng.integers(0, 256, (700_000, 4), dtype=np.uint8),
                       {"intensity": rng.integers(0, 256, 700_000).astype(np.uint8)}),
            PointChunk(rng.uniform(0, 100, (500, 3)), rng.integers(0, 256, (500, 4), dtype=np.uint8),
                       {"intensity": rng.integers(256, 60_000, 500).astype(np.uint16)}),
        ]  # fmt: skip
        joined = cloud._joined([p.attributes["intensity"] for p in parts])
        assert joined.dtype == np.uint16
        np.testing.assert_array_equal(joined, np.concatenate([p.attributes["intensity"] for p in parts]))
        xyz = cloud._joined([p.xyz for p in parts])
        np.testing.assert_array_equal(xyz, np.concatenate([p.xyz for p in parts]))
        assert cloud._joined([parts[0].xyz]) is parts[0].xyz  # one chunk: not copied
        c = build_cloud(iter(parts), layout="words", colors="rgba")
        assert c.n_points == 700_500
        got = np.sort(c.attributes["intensity"][:].astype(np.int64))
        np.testing.assert_array_equal(got, np.sort(np.concatenate([p.attributes["intensity"] for p in parts]).astype(np.int64)))
    finally:
        pages._madvise.cache_clear()


def test_chunks_refuse_an_odd_size():
    """cloud.chunks(0), chunks(-1) and chunks(2.5) were taken (one batch a chunk, whatever was asked)."""
    cloud = gp.from_arrays(np.random.default_rng(0).random((3000, 3)), name="c")
    for bad in (0, -1, 2.5, "a"):
        with pytest.raises(InputError, match=rf"^c: chunks: points_per_chunk must be an integer >= 1, got {re.escape(repr(bad))}$"):
            list(cloud.chunks(bad))
    assert sum(len(c) for c in cloud.chunks(1000)) == 3000


@pytest.mark.parametrize("dtype", [np.bool_, np.int8, np.uint16, np.float32, np.float64, np.complex128])
@pytest.mark.parametrize("shape", [(), (3,)])
def test_take_and_gather_are_numpys_fancy_indexing(dtype, shape):
    """``take`` (the parallel gather of the converter, the octrees and the chunked cloud) and
    ``gather`` (numpy up to NUMPY_MAX rows, take beyond; both by the fixture) give
    ``values[order]``: 1-D and rows of 3, any item size (moved as same-width integers; others by
    numpy), indices of any integer type, a strided source, into a slice of a larger output."""
    rng = np.random.default_rng(5)
    n = 5_000
    values = (rng.standard_normal((2 * n, *shape)) * 100).astype(dtype)[::2]  # strided
    order = rng.permutation(n)[: n - 7]
    want = values[order]
    for idx in (order, order.astype(np.uint32), order.astype(np.int32), order.astype(np.int16)):
        got = cloud.take(values, idx)
        assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)
    out = np.zeros((len(order) + 10, *shape), dtype)
    cloud.take(values, order, out=out[5:-5])
    assert np.array_equal(out[5:-5], want) and not out[:5].any() and not out[-5:].any()
    got = gather(values, order)
    assert got.dtype == want.dtype and np.array_equal(got, want) and got.flags.c_contiguous


def test_the_chunks_are_let_go_once_joined(monkeypatch):
    """build_cloud joins the chunks' arrays, then sorts and quantizes the joined ones: the chunks'
    own arrays (the last chunk's and the attributes' included) are no longer held by then. Held
    to the end, they were a second copy of every attribute through the sort (a 20 M-point LAS
    opened: peak 2 015 -> 1 645 MiB)."""
    import gc
    import weakref

    from gigapoint.core.chunk import PointChunk

    alive = []

    def chunk(i):
        rng = np.random.default_rng(i)
        xyz, rgba = rng.uniform(0, 100, (1000, 3)), rng.integers(0, 255, (1000, 4), dtype=np.uint8)
        attrs = {"intensity": rng.integers(0, 9, 1000).astype(np.uint16), "gps_time": rng.uniform(0, 1, 1000)}
        alive.extend(weakref.ref(a) for a in (xyz, rgba, *attrs.values()))
        return PointChunk(xyz, rgba, attrs)

    seen = []
    real = cloud.cloud_from_points

    def sorting(*args, **kwargs):
        gc.collect()
        seen.append(sum(r() is not None for r in alive))
        return real(*args, **kwargs)

    monkeypatch.setattr(cloud, "cloud_from_points", sorting)
    built = cloud.build_cloud((chunk(i) for i in range(3)), name="three")
    assert len(built) == 3000 and seen == [0]
