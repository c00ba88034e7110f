import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import gigapoint as gp
from gigapoint.core.quantize import dequantize, fixed_point, make_batches, quantize

finite = st.floats(-1e7, 1e7, allow_nan=False, allow_infinity=False)


def _one_batch(xyz):
    order = np.arange(len(xyz))
    batches = make_batches(len(xyz), len(xyz))
    low, med, high = quantize(xyz, order, batches)
    return batches[0], low, med, high


@settings(max_examples=80, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 60), st.just(3)), elements=finite))
def test_round_trip_within_one_30_bit_step(xyz):
    rec, low, med, high = _one_batch(xyz)
    lo, hi = rec["bbox_min"], rec["bbox_max"]
    np.testing.assert_array_equal(lo, xyz.min(axis=0))
    np.testing.assert_array_equal(hi, xyz.max(axis=0))
    step = (hi - lo) / 2**30
    back = dequantize(low, med, high, lo, hi, 30)
    err = np.abs(back - xyz)
    # one 30-bit step, plus float64 rounding of the arithmetic on large coordinates
    assert np.all(err <= step + 4 * np.spacing(np.abs(xyz) + np.abs(lo) + 1.0))


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 60), st.just(3)), elements=finite), st.sampled_from([10, 20]))
def test_lower_precision_decodes_stay_inside_the_box(xyz, bits):
    rec, low, med, high = _one_batch(xyz)
    lo, hi = rec["bbox_min"], rec["bbox_max"]
    back = dequantize(low, med, high, lo, hi, bits)
    assert np.all(back >= lo - 1e-9 * (np.abs(lo) + 1)) and np.all(back <= hi + 1e-9 * (np.abs(hi) + 1))
    step = (hi - lo) / 2**bits
    assert np.all(np.abs(back - xyz) <= step + 1e-9 * (np.abs(xyz) + 1))


def test_word_layout_matches_the_contract():
    # a point at the box max on x, min on y, and exactly in the middle on z
    xyz = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 1.0]])
    _, low, med, high = _one_batch(xyz)
    q = fixed_point(low, med, high, 30)
    assert q[1].tolist() == [2**30 - 1, 0, 2**29]
    # low word packs bits 20-29 of x | y << 10 | z << 20
    assert low[1] == (1023 | (0 << 10) | (512 << 20))
    assert med[1] == (1023 | (0 << 10) | (0 << 20))
    assert high[1] == 1023


def test_degenerate_axis_is_legal():
    xyz = np.array([[5.0, 1.0, 7.0], [6.0, 1.0, 7.0], [5.5, 1.0, 7.0]])
    rec, low, med, high = _one_batch(xyz)
    back = dequantize(low, med, high, rec["bbox_min"], rec["bbox_max"], 30)
    np.testing.assert_allclose(back[:, 1:], xyz[:, 1:])
    assert np.abs(back[:, 0] - xyz[:, 0]).max() <= 1.0 / 2**30


def test_cloud_positions_round_trip_utm_coordinates(rng):
    xyz = rng.random((50_000, 3)) * [2000.0, 2000.0, 100.0] + [637_000.0, 851_000.0, 120.0]
    cloud = gp.from_arrays(xyz)
    back = cloud.positions()
    # the cloud reorders points: compare as sorted sets of rows via nearest match on the Morton order
    order = np.lexsort(xyz.T)
    order_back = np.lexsort(back.T)
    assert np.abs(back[order_back] - xyz[order]).max() < 1e-5
    assert len(cloud.batches) == 5
    assert cloud.batches["count"].sum() == 50_000


@pytest.mark.parametrize("n", [1, 10_239, 10_240, 10_241])
def test_batches_cover_every_point_once(n, rng):
    cloud = gp.from_arrays(rng.random((n, 3)))
    b = cloud.batches
    assert b["first"][0] == 0
    np.testing.assert_array_equal(b["first"][1:], b["first"][:-1] + b["count"][:-1])
    assert int(b["count"].sum()) == n
    assert np.all(b["count"] <= 10_240)
