"""Read-time point filters (io/filters.py): gp.open's ``classes``, ``drop_classes`` and ``clip``,
in memory and progressive, and render's ``--classes``/``--drop-classes``/``--clip``, checked
against numpy on autzen's classification; every bad value is a one-line error before reading."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, InputError
from gigapoint.io import read_chunks
from gigapoint.io.filters import PointFilter

CLIP_2D = (636_500.0, 849_000.0, 637_000.0, 849_300.0)
CLIP_3D = (636_500.0, 849_000.0, 420.0, 637_000.0, 849_300.0, 440.0)


@pytest.fixture(scope="module")
def autzen(autzen_path):
    """autzen's positions and classification as the reader gives them (the numpy reference)."""
    chunks = list(read_chunks(autzen_path))
    return np.concatenate([c.xyz for c in chunks]), np.concatenate([c.attributes["classification"] for c in chunks])


def _in_box(xyz: np.ndarray, box) -> np.ndarray:
    axes = len(box) // 2
    return np.all((xyz[:, :axes] >= box[:axes]) & (xyz[:, :axes] <= box[axes:]), axis=1)


def test_open_keeps_only_the_classes_given(autzen_path, autzen):
    _, classification = autzen
    cloud = gp.open(autzen_path, classes=[2])
    assert cloud.n_points == np.count_nonzero(np.isin(classification, [2])) == 26_107
    assert set(np.unique(cloud.attributes["classification"])) == {2}
    assert gp.open(autzen_path, classes=[1, 2, 6]).n_points == 110_000  # (classes the file lacks keep nothing more)


def test_open_drops_the_classes_given(autzen_path, autzen):
    _, classification = autzen
    cloud = gp.open(autzen_path, drop_classes=2)  # one class as an integer
    assert cloud.n_points == np.count_nonzero(~np.isin(classification, [2])) == 83_893
    assert set(np.unique(cloud.attributes["classification"])) == {1}


@pytest.mark.parametrize("box", [CLIP_2D, CLIP_3D], ids=["2d", "3d"])
def test_open_keeps_the_points_in_the_clip_box(autzen_path, autzen, box):
    xyz, classification = autzen
    inside = _in_box(xyz, box)
    cloud = gp.open(autzen_path, clip=box)
    assert cloud.n_points == np.count_nonzero(inside) > 0
    kept = cloud.positions()
    assert np.all(_in_box(kept, box))
    both = gp.open(autzen_path, clip=box, classes=[2])  # a point passes every option given
    assert both.n_points == np.count_nonzero(inside & (classification == 2))


def test_progressive_open_reads_the_points_the_filter_keeps(autzen_path, autzen):
    xyz, classification = autzen
    cloud = gp.open(autzen_path, progressive=True, drop_classes=[2], clip=CLIP_2D)
    assert cloud.wait(timeout=120)
    assert cloud.n_points == np.count_nonzero(~np.isin(classification, [2]) & _in_box(xyz, CLIP_2D))
    # the header's total is an upper bound: the load counts the points read, the filter's left out too
    assert (cloud.loader.read, cloud.loader.total, cloud.progress) == (110_000, 110_000, 1.0)


def test_a_filter_that_keeps_nothing_says_so(autzen_path):
    said = f"{autzen_path}: no point passes the filter (classes 6, 7): 110,000 points read"
    with pytest.raises(EmptyCloudError) as err:
        gp.open(autzen_path, classes=[7, 6])
    assert str(err.value) == said
    with pytest.raises(EmptyCloudError) as err:
        gp.open(autzen_path, chunked=True, classes=[7, 6])  # three passes over the files: counted once
    assert str(err.value) == said
    cloud = gp.open(autzen_path, progressive=True, classes=[6, 7])
    with pytest.raises(EmptyCloudError) as err:
        cloud.wait(timeout=120)
    assert str(err.value) == said
    with pytest.raises(EmptyCloudError) as err:
        gp.open(autzen_path, clip=(0, 0, 1, 1))
    assert str(err.value) == f"{autzen_path}: no point passes the filter (clip 0, 0, 1, 1): 110,000 points read"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"classes": [2, 300]}, "open: classes=[2, 300]: class numbers are integers from 0 to 255 (LAS classes), got 300"),
        ({"classes": [-1]}, "open: classes=[-1]: class numbers are integers from 0 to 255 (LAS classes), got -1"),
        ({"classes": 2.5}, "open: classes=2.5: class numbers are integers from 0 to 255 (LAS classes)"),
        ({"drop_classes": ["7"]}, "open: drop_classes=['7']: class numbers are integers from 0 to 255 (LAS classes), got '7'"),
        ({"classes": []}, "open: classes=[]: class numbers are integers from 0 to 255 (LAS classes), got none"),
        ({"classes": [2, 6], "drop_classes": [6, 7]}, "open: classes= and drop_classes= both name class 6; keep it or drop it"),
        ({"clip": (1, 2, 3, 4, 5)}, "open: clip=(1, 2, 3, 4, 5): a clip box is xmin, ymin, xmax, ymax (any z) or xmin, ymin, zmin, xmax, ymax, zmax; got 5 numbers"),
        ({"clip": (3, 0, 1, 1)}, "open: clip=(3, 0, 1, 1): xmin 3 is above xmax 1"),
        ({"clip": (0, 0, 0, 1, 1, -1)}, "open: clip=(0, 0, 0, 1, 1, -1): zmin 0 is above zmax -1"),
        ({"clip": (0, 0, float("nan"), 1)}, "open: clip=(0, 0, nan, 1): a clip box's bounds are finite numbers"),
        ({"clip": "0,0,1,1"}, "open: clip='0,0,1,1': a clip box is xmin, ymin, xmax, ymax (any z) or xmin, ymin, zmin, xmax, ymax, zmax"),
    ],
)
@pytest.mark.parametrize("progressive", [False, True])
def test_bad_filter_values_are_one_line_errors_before_anything_is_read(tmp_path, options, message, progressive):
    missing = tmp_path / "missing.laz"  # read first, it would be "no such file"
    with pytest.raises(InputError) as err:
        gp.open(missing, progressive=progressive, **options)
    assert str(err.value) == message


def test_a_file_without_classification_given_classes_is_an_error_naming_it(tmp_path):
    f = tmp_path / "plain.xyz"
    np.savetxt(f, np.random.default_rng(1).random((100, 3)))
    with pytest.raises(InputError) as err:
        gp.open(f, drop_classes=[7, 18])
    assert str(err.value) == f"{f}: holds no classification, which the filter (drop classes 7, 18) needs"
    assert gp.open(f, clip=(0, 0, 0.5, 0.5)).n_points > 0  # (a clip box needs none)


# ---------------------------------------------------------------------------------------- CLI

CAMERA = "eye=636590,849216,1100 target=636590,849216,460 up=0,1,0"  # straight down over the survey


def test_render_drop_classes_draws_only_the_points_kept(cli, tmp_path, autzen_path, autzen):
    _, classification = autzen
    size = ("-W", 240, "-H", 160, "--camera", CAMERA)
    rc, out, err = cli("render", autzen_path, "-o", tmp_path / "all.png", "--index-out", tmp_path / "all.npy", *size)
    assert rc == 0, err
    rc, out, err = cli("render", autzen_path, "-o", tmp_path / "ground.png", "--index-out", tmp_path / "ground.npy", "--drop-classes", "1", *size)
    assert rc == 0, err
    ground = np.count_nonzero(classification != 1)
    assert out == f"wrote {tmp_path / 'ground.png'} (240x160, {ground:,} points)\nwrote {tmp_path / 'ground.npy'}\n" and ground == 26_107
    everything, kept = np.load(tmp_path / "all.npy") >= 0, np.load(tmp_path / "ground.npy") >= 0  # pixels a point covers
    # the ground's pixels are the whole cloud's (but a few: adaptive point sizes follow the density), and far fewer
    assert np.count_nonzero(kept & ~everything) <= kept.sum() // 1000
    assert 0.5 * everything.sum() < kept.sum() < 0.8 * everything.sum()  # (12,201 of 16,667 here)
    rc, out, err = cli("render", autzen_path, "-o", tmp_path / "prog.png", "--drop-classes", "1", "--progressive", *size)
    assert rc == 0, err
    assert out.strip() == f"wrote {tmp_path / 'prog.png'} (240x160, 26,107 points)"  # the octree built of the points kept


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--classes", "2,x"], "error: render: --classes 2,x: give integers from 0 to 255, separated by commas"),
        (["--classes", "2,256"], "error: render: --classes 2,256: class numbers are integers from 0 to 255 (LAS classes), got 256"),
        (["--classes", "2,6", "--drop-classes", "6"], "error: render: --classes and --drop-classes both name class 6; keep it or drop it"),
        (["--clip", "1,2,3,4,5"], "error: render: --clip 1,2,3,4,5: a clip box is xmin, ymin, xmax, ymax (any z) or xmin, ymin, zmin, xmax, ymax, zmax; got 5 numbers"),
        (["--clip", "0,0,nan,1"], "error: render: --clip 0,0,nan,1: a clip box's bounds are finite numbers"),
        (["--clip", "0,0,a,1"], "error: render: --clip 0,0,a,1: give numbers, separated by commas"),
    ],
)
def test_render_bad_filter_values_are_one_line_errors(cli, tmp_path, args, message):
    rc, _, err = cli("render", tmp_path / "missing.laz", "-o", tmp_path / "x.png", *args)
    assert rc != 0
    assert err.strip() == message


def test_render_says_when_the_filter_keeps_nothing(cli, tmp_path, autzen_path):
    rc, _, err = cli("render", autzen_path, "-o", tmp_path / "x.png", "--classes", "7,18")
    assert rc != 0
    assert err.strip() == f"error: {autzen_path}: no point passes the filter (classes 7, 18): 110,000 points read"


def test_view_filter_options_need_files(cli):
    rc, _, err = cli("view", "--demo", 100, "--classes", "2")
    assert rc != 0
    assert err.strip() == "error: --classes, --drop-classes, --clip and --clip-polygon: filter the points of the files given as PATH...; none is given"


@pytest.mark.parametrize(
    ("clip", "message"),
    [
        ((1e13, 0.0, 5.0, 1.0), "open: clip=(1e+13, 0, 5, 1): xmin 1e+13 is above xmax 5"),
        ((0.0, 0.0, 0.1 + 0.2, 1.0, 1.0, 0.3), "open: clip=(0, 0, 0.30000000000000004, 1, 1, 0.3): zmin 0.30000000000000004 is above zmax 0.3"),
        ([1e13, 0.0, 5.0, 1.0], "open: clip=[1e+13, 0, 5, 1]: xmin 1e+13 is above xmax 5"),
        (np.array([1e13, 0.0, 5.0, 1.0]), "open: clip=[1e+13, 0, 5, 1]: xmin 1e+13 is above xmax 5"),
    ],
)
def test_a_clip_box_error_spells_its_bounds_compactly_and_exactly(tmp_path, clip, message):
    """A min above its max is said as ``errors.number_text`` spells numbers: 1e13 was
    '10000000000000', and 0.1 + 0.2 above 0.3 read '0.3 is above zmax 0.3' ('%.15g'); the
    box given, at the message's start, too (its repr said 10000000000000.0, numpy's array([1.e+13, ...]))."""
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", clip=clip)
    assert str(err.value) == message


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"classes": [np.int64(2), np.int64(300)]}, "open: classes=[2, 300]: class numbers are integers from 0 to 255 (LAS classes), got 300"),
        ({"drop_classes": np.array([7, 300])}, "open: drop_classes=[7, 300]: class numbers are integers from 0 to 255 (LAS classes), got 300"),
        ({"classes": [2.0]}, "open: classes=[2.0]: class numbers are integers from 0 to 255 (LAS classes), got 2.0"),
        ({"corridor": (1e13, 0.0, 1e13, 0.0, 1.0)}, "open: corridor=(1e+13, 0, 1e+13, 0, 1): a line's end lies beyond ±1e+12: no point can be there"),
    ],
)
def test_filter_labels_spell_numpy_integers_as_digits_and_floats_compactly(tmp_path, options, message):
    """Classes given as numpy integers were said np.int64(300) (a float class stays 2.0: why it
    is refused); a corridor's numbers as errors.number_text spells them, as the message does."""
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", **options)
    assert str(err.value) == message


BOX = "a clip box is xmin, ymin, xmax, ymax (any z) or xmin, ymin, zmin, xmax, ymax, zmax"
CLASSES = "class numbers are integers from 0 to 255 (LAS classes)"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"clip": np.zeros((2, 3))}, f"open: clip=a 2x3 array: {BOX}"),  # (its 2 rows were "got 2 numbers")
        ({"clip": np.zeros((2, 2, 2))}, f"open: clip=a 2x2x2 array: {BOX}"),
        ({"clip": np.array(5.0)}, f"open: clip=array(5.): {BOX}"),  # (0-d: a TypeError, "iteration over a 0-d array")
        ({"classes": np.zeros((2, 3), int)}, f"open: classes=a 2x3 array: {CLASSES}"),
        ({"drop_classes": np.array(7)}, f"open: drop_classes=array(7): {CLASSES}"),
        ({"corridor": np.zeros((2, 3))}, "open: corridor=a 2x3 array: a corridor is x1, y1, x2, y2, width (a line's two ends and the corridor's width)"),
        ({"clip_polygon": np.zeros((4, 2))}, "open: clip_polygon=a 4x2 array: a clip polygon is a GeoJSON or WKT file, or WKT text (POLYGON ((x y, ...)))"),
        ({"clip_polygon": np.arange(100.0)}, "open: clip_polygon=an array of 100 values: a clip polygon is a GeoJSON or WKT file, or WKT text (POLYGON ((x y, ...)))"),
    ],
    ids=["clip-2d", "clip-3d", "clip-0d", "classes-2d", "drop-classes-0d", "corridor-2d", "polygon-2d", "polygon-long-1d"],
)
def test_an_array_of_other_than_one_dimension_is_said_in_one_line(tmp_path, options, message):
    """A numpy array of several dimensions (or a long one, its repr wrapped) was quoted by its
    repr, rows over several lines, in what must be one line; now by its shape (errors.one_line_repr)."""
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", **options)
    assert str(err.value) == message


def test_box_shares_are_the_share_of_each_box_inside_the_clip_box():
    """What an LOD octree weighs a node not loaded by (lod/store.py): the share of its box's
    area in x and y (volume with a clip box in z) inside the clip box; 1 where it cannot tell."""
    lo = np.array([[0.0, 0, 0], [0, 0, 0], [20, 0, 0], [5, 5, 3], [0, 0, 0]])
    hi = np.array([[10.0, 10, 10], [20, 10, 10], [30, 10, 10], [5, 5, 3], [10, 10, 10]])
    shares = PointFilter(clip=(0.0, 0.0, 10.0, 5.0)).box_shares(lo, hi)
    # inside half in y; a quarter; outside; a point-like box inside; as the first
    assert shares.tolist() == [0.5, 0.25, 0.0, 1.0, 0.5]
    assert PointFilter(clip=(0.0, 0.0, 0.0, 10.0, 10.0, 2.5)).box_shares(lo[:1], hi[:1]).tolist() == [0.25]
    assert PointFilter(classes=(2,), corridor=(0.0, 0.0, 10.0, 0.0, 2.0)).box_shares(lo, hi).tolist() == [1.0] * 5
