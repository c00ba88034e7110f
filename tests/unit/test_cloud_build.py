"""The compiled point scan and gather used by build_cloud, against numpy."""

import numpy as np
import pytest

from gigapoint.core import cloud
from gigapoint.core.cloud import MAX_ABS_COORDINATE, _valid_mask, gather, scan_points


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
