import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gigapoint.core import morton
from gigapoint.core.morton import morton_codes, morton_order


@pytest.fixture(autouse=True, scope="module", params=["numpy below the threshold", "the compiled radix sort"])
def sort_path(request):
    """Every order test runs on both paths: numpy's stable sort (small inputs) and the radix sort."""
    default = morton.NUMPY_SORT_MAX
    morton.NUMPY_SORT_MAX = default if request.param.startswith("numpy") else 0
    yield
    morton.NUMPY_SORT_MAX = default


def reference_code(cell):
    """Bit-by-bit interleave: x in bit 0, y in bit 1, z in bit 2."""
    code = 0
    for bit in range(21):
        for axis in range(3):
            code |= ((int(cell[axis]) >> bit) & 1) << (3 * bit + axis)
    return code


def test_codes_match_bitwise_interleave(rng):
    xyz = rng.random((500, 3)) * 10 - 5
    codes = morton_codes(xyz, np.array([-5.0, -5.0, -5.0]), 10.0)
    cells = np.minimum(((xyz + 5) / 10 * 2**21).astype(np.int64), 2**21 - 1)
    assert [int(c) for c in codes] == [reference_code(c) for c in cells]


def test_codes_clamp_to_cube():
    xyz = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, -1.0, 0.5]])
    codes = morton_codes(xyz, np.zeros(3), 1.0)
    assert codes[0] == 0
    assert codes[1] == (1 << 63) - 1  # every bit of 21 x 3 set
    assert codes[2] == reference_code([2**21 - 1, 0, 2**20])


@pytest.mark.parametrize("n", [0, 1, 2, 47, 49, 1000, 300_000])
def test_order_equals_stable_argsort(rng, n):
    codes = rng.integers(0, 2**63 - 1, n, dtype=np.int64).astype(np.uint64)
    if n > 10:
        codes[: n // 3] = codes[n // 3 : 2 * (n // 3)]  # many duplicates: stability matters
    order = morton_order(codes)
    np.testing.assert_array_equal(order, np.argsort(codes, kind="stable"))


def test_order_on_flat_and_clustered_clouds(rng):
    # a flat cloud: z constant, so a third of the bits never vary (passes get skipped)
    xyz = rng.random((200_000, 3))
    xyz[:, 2] = 0.25
    xyz[:1000] = xyz[0]  # a cluster of identical points
    codes = morton_codes(xyz, np.zeros(3), 1.0)
    np.testing.assert_array_equal(morton_order(codes), np.argsort(codes, kind="stable"))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 2**63 - 1), max_size=300))
def test_order_property(values):
    codes = np.array(values, np.uint64)
    np.testing.assert_array_equal(morton_order(codes), np.argsort(codes, kind="stable"))


@pytest.mark.parametrize("shared_bits", [3, 9, 12, 13, 30, 60])
def test_order_of_codes_sharing_a_prefix(rng, shared_bits):
    """An octree partition's codes share their top bits: the buckets move below them."""
    free = 63 - shared_bits
    prefix = np.uint64(int(rng.integers(0, 2**shared_bits))) << np.uint64(free)
    low = rng.integers(0, 2**free, 300_000, dtype=np.uint64) if free < 63 else rng.integers(0, 2**62, 300_000, dtype=np.uint64)
    low[::7] = low[3]  # ties: the order must stay stable
    codes = prefix | low
    np.testing.assert_array_equal(morton_order(codes), np.argsort(codes, kind="stable"))


@pytest.mark.parametrize("kind", ["quicksort", "stable"])
def test_argsort_codes_sorts_with_either_of_numpys_sorts(kind, monkeypatch):
    """Whichever sort the CPU favours, the permutation sorts the codes (ties in any order)."""
    from gigapoint.core import morton

    monkeypatch.setattr(morton, "_SORT_KIND", [kind])
    rng = np.random.default_rng(5)
    codes = np.concatenate([np.sort(rng.integers(0, 1 << 40, 5000, dtype=np.uint64)), rng.integers(0, 1 << 20, 5000, dtype=np.uint64)])
    perm = morton.argsort_codes(codes)
    np.testing.assert_array_equal(np.sort(perm), np.arange(len(codes)))
    np.testing.assert_array_equal(codes[perm], np.sort(codes))


def test_the_faster_sort_is_chosen_once(monkeypatch):
    from gigapoint.core import morton

    monkeypatch.setattr(morton, "_SORT_KIND", [])
    kind = morton._faster_sort_kind()
    assert kind in ("quicksort", "stable") and morton._SORT_KIND == [kind] and morton._faster_sort_kind() == kind
