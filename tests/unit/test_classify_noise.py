"""Noise classification as lasnoise does it (noise.py, ``gigapoint classify --noise``):
isolated points planted around a synthetic surface found and nothing else, autzen's flagged
points checked against a brute-force neighbour count, every point and attribute kept, one-line
errors."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError


def _write_las(path, xyz, classification):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = classification.astype(np.uint8)
    las.intensity = np.arange(len(xyz)) % 65536
    las.write(str(path))
    return path


def _surface_with_noise(rng):
    """(xyz, classes, planted, cluster): 120 x 120 m of sloped, undulating ground (1 point/m²,
    class 2), 25 points 15-60 m above it and 25 15-40 m below it (planted:
    their rows), and 20 points within 1 m of each other 30 m up (cluster: their rows)."""
    def terrain(x, y):
        return 0.1 * x + 3.0 * np.sin(x / 20.0) * np.cos(y / 15.0)

    ground = rng.uniform(0, 120, (14_400, 2))
    ground = np.column_stack([ground, terrain(*ground.T)])
    at = rng.uniform(0, 120, (50, 2))
    off = np.r_[rng.uniform(15, 60, 25), -rng.uniform(15, 40, 25)]
    planted = np.column_stack([at, terrain(*at.T) + off])
    centre = np.array([60.0, 60.0, terrain(60.0, 60.0) + 30.0])
    cluster = centre + rng.uniform(-0.5, 0.5, (20, 3))
    xyz = np.vstack([ground, planted, cluster])
    classes = np.r_[np.full(len(ground), 2), np.ones(70)]
    rows = np.arange(len(xyz))
    return xyz, classes, rows[len(ground):len(ground) + 50], rows[len(ground) + 50:]


@pytest.fixture(scope="module")
def surface(tmp_path_factory):
    xyz, classes, planted, cluster = _surface_with_noise(np.random.default_rng(7))
    return _write_las(tmp_path_factory.mktemp("surface") / "surface.las", xyz, classes), planted, cluster


def test_the_planted_points_are_found_and_nothing_else(surface, tmp_path):
    path, planted, cluster = surface
    result = gp.classify_noise(path, tmp_path / "out.laz")
    got = np.asarray(laspy.read(str(tmp_path / "out.laz")).classification)
    assert (got[planted] == 7).all()
    assert (got[cluster] == 1).all()  # 19 others around each: no noise with isolated 5
    assert (got[: planted[0]] == 2).all()  # no ground point flagged (its 27 cells hold 144 points, about)
    assert (result.points, result.noise, result.kept_noise) == (14_470, 50, 0)
    assert result.params == {"step": 4.0, "step_z": 4.0, "isolated": 5, "units": "m (assumed)", "height_units": "m (assumed)"}  # lasnoise's defaults, no CRS: metres


def test_isolated_is_the_most_other_points_in_the_27_cells(surface, tmp_path):
    """The cluster's 20 points each have 19 others within its cells: noise with isolated 19, not with 18 (lasnoise's -isolated)."""
    path, planted, cluster = surface
    for isolated, cluster_class in ((18, 1), (19, 7)):
        gp.classify_noise(path, tmp_path / f"{isolated}.las", isolated=isolated)
        got = np.asarray(laspy.read(str(tmp_path / f"{isolated}.las")).classification)
        assert (got[cluster] == cluster_class).all() and (got[planted] == 7).all() and (got[: planted[0]] == 2).all()


def test_small_chunks_give_the_same_classes(surface, tmp_path):
    """The counts are of the whole stream: a table grown (and rehashed) over 15 chunks counts what one chunk does."""
    path, planted, _ = surface
    whole = gp.classify_noise(path, tmp_path / "whole.las")
    chunked = gp.classify_noise(path, tmp_path / "chunked.las", chunk_size=1_000)
    a, b = (np.asarray(laspy.read(str(tmp_path / n)).classification) for n in ("whole.las", "chunked.las"))
    np.testing.assert_array_equal(a, b)
    assert chunked.noise == whole.noise == 50 and chunked.cells == whole.cells
    assert 16 <= chunked.table_bytes / chunked.cells <= 32  # (a uint64 key and a uint32 count a slot, 3/8 to 3/4 full)


def test_noise_already_classified_keeps_its_class(tmp_path):
    xyz, classes, planted, _ = _surface_with_noise(np.random.default_rng(7))
    classes[planted[:5]] = 18  # high noise already
    classes[:3] = 7  # ground points someone called noise
    path = _write_las(tmp_path / "in.las", xyz, classes)
    result = gp.classify_noise(path, tmp_path / "out.las")
    got = np.asarray(laspy.read(str(tmp_path / "out.las")).classification)
    assert (got[planted[:5]] == 18).all() and (got[planted[5:]] == 7).all() and (got[:3] == 7).all()
    assert (result.noise, result.kept_noise) == (45, 8)


def test_with_ground_the_noise_is_found_first(surface, tmp_path):
    path, planted, cluster = surface
    result = gp.classify_ground(path, tmp_path / "out.laz", noise=True)
    got = np.asarray(laspy.read(str(tmp_path / "out.laz")).classification)
    assert (got[planted] == 7).all() and result.isolated == result.noise == 50
    assert (got[cluster] == 1).all()
    assert (got[: planted[0]] == 2).mean() >= 0.999  # the ground found under the noise
    assert result.params["step"] == 4.0 and result.params["isolated"] == 5


def test_with_ground_the_noise_is_true_false_or_a_dict_of_its_parameters(surface, tmp_path):
    """classify_ground(noise={"stepp": 3}) was a raw TypeError (noise_parameters() got an
    unexpected keyword argument), noise="yes" and noise=1 "argument after ** must be a mapping"."""
    path, _, _ = surface
    for value in ({"stepp": 3}, {"step": 5, "cell": 2}, "yes", 1, [("step", 5)]):
        with pytest.raises(InputError) as caught:
            gp.classify_ground(path, tmp_path / "out.laz", noise=value)
        assert str(caught.value) == f"classify_ground: noise must be True, False or a dict of step, step_z, isolated, got {value!r}"
    assert list(tmp_path.iterdir()) == []
    result = gp.classify_ground(path, tmp_path / "out.laz", noise={"step": 5, "isolated": 3})
    assert result.params["step"] == result.params["step_z"] == 5.0 and result.params["isolated"] == 3 and result.isolated > 0
    result = gp.classify_ground(path, tmp_path / "out.laz", noise=False, overwrite=True)
    assert "isolated" not in result.params and result.isolated == 0


def test_with_ground_the_noise_is_marked_in_the_input_files_own_passes(surface, tmp_path, monkeypatch):
    """classify_ground(noise=...) marks the noise in the chunks its passes read from the input
    files themselves, not through a stand-in that copied their fields by hand (one did, and a
    field PointFiles gained would have been missing from it): a field added is seen by the
    written pass."""
    from gigapoint.lod.convert import to_file
    from gigapoint.survey import ground

    class WithFlight(to_file.PointFiles):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.flight = "flight 12"

    seen = []
    real = ground.write_through

    def spying(inputs, *args):
        seen.append(inputs.flight)
        return real(inputs, *args)

    monkeypatch.setattr(to_file, "PointFiles", WithFlight)
    monkeypatch.setattr(ground, "write_through", spying)
    path, planted, _ = surface
    result = gp.classify_ground(path, tmp_path / "out.laz", noise=True)
    assert seen == ["flight 12"] and result.isolated == 50
    assert (np.asarray(laspy.read(str(tmp_path / "out.laz")).classification)[planted] == 7).all()


def test_autzen_flags_few_points_each_in_a_sparse_neighbourhood(autzen_path, tmp_path):
    """autzen_trim (feet: the 4 m cells are 13.12 ft) has 67 points flagged with the defaults.
    Brute force (cKDTree, Chebyshev distance): a flagged point has at most 5 others nearer than
    a cell's edge (they would share its 27 cells), an unflagged one more than 5 within two
    cells' edges (its 27 cells lie within them)."""
    from scipy.spatial import cKDTree

    result = gp.classify_noise(autzen_path, tmp_path / "out.laz")
    step = result.params["step"]
    assert step == pytest.approx(4 / 0.3048) and result.params["step_z"] == pytest.approx(4 / 0.3048)
    las = laspy.read(str(tmp_path / "out.laz"))
    flagged = np.asarray(las.classification) == 7
    assert flagged.sum() == result.noise == 67  # 0.06 % of the points
    xyz = np.column_stack([las.x, las.y, las.z])
    tree = cKDTree(xyz)
    near = tree.query_ball_point(xyz[flagged], step * 0.999, p=np.inf, return_length=True)
    assert near.max() <= 6  # itself and 5 others at most
    within_two = tree.query_ball_point(xyz[~flagged], 2 * step, p=np.inf, return_length=True)
    assert within_two.min() >= 7


def test_the_output_keeps_every_point_and_attribute(autzen_path, tmp_path):
    gp.classify_noise(autzen_path, tmp_path / "out.laz")
    a, b = laspy.read(str(autzen_path)), laspy.read(str(tmp_path / "out.laz"))
    assert len(a.points) == len(b.points) == 110_000
    for name in ("X", "Y", "Z", "intensity", "return_number", "number_of_returns", "point_source_id", "gps_time", "red", "green", "blue"):
        np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), err_msg=name)
    flagged = np.asarray(b.classification) == 7
    np.testing.assert_array_equal(np.asarray(a.classification)[~flagged], np.asarray(b.classification)[~flagged])
    assert b.header.parse_crs() is not None


def test_bad_parameters_are_one_line_errors(surface, tmp_path):
    path, _, _ = surface
    for name, value, least in (("step", 0.0, "a number > 0"), ("step_z", float("nan"), "a number > 0"), ("step", "4", "a number > 0"),
                               ("isolated", -1, "a whole number >= 0"), ("isolated", 2.5, "a whole number >= 0"), ("isolated", True, "a whole number >= 0")):  # fmt: skip
        with pytest.raises(InputError, match=f"^classify_noise: {name} must be {least}, got"):
            gp.classify_noise(path, tmp_path / "a.laz", **{name: value})
    with pytest.raises(InputError, match=r"^classify_noise: step 1e-12: cells too small for the data's extent \(.*surface.las: "):
        gp.classify_noise(path, tmp_path / "a.laz", step=1e-12)
    with pytest.raises(InputError, match="a.txt: classify_noise writes a .las, .laz or .ply file"):
        gp.classify_noise(path, tmp_path / "a.txt")
    (tmp_path / "there.laz").write_bytes(b"mine")
    with pytest.raises(InputError, match="there.laz: already exists; pass overwrite=True"):
        gp.classify_noise(path, tmp_path / "there.laz")
    assert (tmp_path / "there.laz").read_bytes() == b"mine"
    assert [p.name for p in tmp_path.iterdir()] == ["there.laz"]  # no output left by a refused run


def test_the_cli_classifies_noise_and_names_its_options(cli, surface, tmp_path):
    path, _, _ = surface
    rc, out, err = cli("classify", path, "-o", tmp_path / "out.laz", "--noise", "-q")
    assert rc == 0, err
    assert out.startswith(f"{tmp_path / 'out.laz'}: 14,470 points, 50 isolated found noise (7); step 4 x 4 m (assumed), isolated 5; ")
    rc, _, err = cli("classify", path, "-o", tmp_path / "out.laz", "--noise")
    assert rc != 0 and err.strip().endswith("out.laz: already exists; pass --overwrite to replace it") and len(err.strip().splitlines()) == 1
    for option, value, message in (("--step-z", "-1", "classify: --step-z must be a number > 0, got -1"),
                                   ("--isolated", "-2", "classify: --isolated must be a whole number >= 0, got -2"),
                                   ("--step", "1e-12", "classify: --step 1e-12: cells too small")):  # fmt: skip
        rc, _, err = cli("classify", path, "-o", tmp_path / "b.laz", "--noise", option, value)
        assert rc != 0 and message in err and len(err.strip().splitlines()) == 1, err
    rc, out, err = cli("classify", path, "-o", tmp_path / "both.laz", "--noise", "--ground", "--step", "5", "-q")
    assert rc == 0, err
    assert " ground (2), " in out and "50 isolated found noise (7; step 5 x 5 m (assumed), isolated 5)" in out  # (said without its unit before)
    rc, _, err = cli("classify", path, "-o", tmp_path / "b.laz", "--ground", "--noise", "--isolated", "-1")
    assert rc != 0 and "classify: --isolated must be a whole number >= 0, got -1" in err
    rc, _, err = cli("classify", path, "-o", tmp_path / "b.laz")
    assert rc != 0 and "classify: say what to classify: --ground, --noise, --height-above-ground, or several" in err
    assert not (tmp_path / "b.laz").exists()


@pytest.mark.parametrize(("modes", "options", "message"), [
    (["--ground"], ["--step", "1000", "--isolated", "100000"], "classify: --step, --isolated are for the noise classification: give --noise too"),
    (["--noise"], ["--cell", "1000", "--window", "5", "--slope", "9"],
     ("classify: --cell is for the ground classification or the heights above ground: give --ground or --height-above-ground too; "
     "--slope, --window are for the ground classification: give --ground too")),
    (["--height-above-ground"], ["--step", "5"], "classify: --step is for the noise classification: give --noise too"),
    (["--height-above-ground"], ["--step-z", "5", "--threshold", "1"],
     "classify: --threshold is for the ground classification: give --ground too; --step-z is for the noise classification: give --noise too"),
    (["--normalize"], ["--scalar", "2"], "classify: --scalar is for the ground classification: give --ground too"),
])  # fmt: skip
def test_the_cli_refuses_an_option_no_chosen_classification_uses(cli, surface, tmp_path, modes, options, message):
    """--ground --step 1000, --noise --cell 1000 and --height-above-ground --step 5 ran with
    the options ignored (exit 0); only --height-above-ground alone refused SMRF's options."""
    path, _, _ = surface
    rc, _, err = cli("classify", path, "-o", tmp_path / "out.laz", *modes, *options, "-q")
    assert rc != 0 and err == f"error: {message}\n"
    assert list(tmp_path.iterdir()) == []


def test_the_cli_names_height_above_grounds_cell_as_its_option(cli, surface, tmp_path):
    """--height-above-ground --cell -1 said "classify: cell must be ...": the option's name was
    looked for in classify_ground's words, not height_above_ground's."""
    path, _, _ = surface
    rc, _, err = cli("classify", path, "-o", tmp_path / "out.laz", "--height-above-ground", "--cell", "-1")
    assert rc != 0 and err == "error: classify: --cell must be a number > 0, got -1\n"


def test_coordinates_in_degrees_need_both_steps_given(tmp_path):
    """In WGS 84 the default step (4 m) has no length in degrees: refused in the one wording the
    surveys refuse degrees in (io.crs.refuse_angles), the UTM zone the points lie in offered;
    both steps given, it runs in them."""
    from test_change import refused_writing_nothing, write_degrees_grid  # (tests/unit is on sys.path)

    path = write_degrees_grid(tmp_path / "wgs84.las", 20)
    assert refused_writing_nothing(gp.classify_noise, path, tmp_path / "out.laz", step=0.00004) == (
        f"classify_noise: {path} has coordinates in degrees (EPSG:4326); a default step_z (4 m) needs metres or feet: "
        "give both, or reproject first (gigapoint convert --to-crs EPSG:32610, WGS 84 / UTM zone 10N, where the data lie)"
    )
    assert refused_writing_nothing(gp.classify_noise, path, tmp_path / "out.laz").startswith(
        f"classify_noise: {path} has coordinates in degrees (EPSG:4326); a default step (4 m) or step_z (4 m) needs metres or feet: give both, or "
    )
    result = gp.classify_noise(path, tmp_path / "out.laz", step=0.00004, step_z=4.0)
    assert (result.params["step"], result.params["step_z"], result.noise) == (0.00004, 4.0, 0)


def test_the_cli_says_each_step_in_its_unit_in_degrees(tmp_path, cli):
    """A cloud in WGS 84 with heights in metres: its steps were said 'step 4e-05 x 4 °' (both in
    the horizontal unit); now the width in degrees, the height in metres."""
    from test_change import EPSG_4326_METRES_UP_KEYS, write_degrees_grid  # (tests/unit is on sys.path)

    path = write_degrees_grid(tmp_path / "wgs84.las", 20, keys=EPSG_4326_METRES_UP_KEYS)
    rc, out, err = cli("classify", path, "-o", tmp_path / "out.las", "--noise", "--step", "0.00004", "--step-z", "4", "-q")
    assert rc == 0, err
    assert ": 400 points, 0 isolated found noise (7); step 4e-05 ° x 4 m, isolated 5; " in out
    # with --ground: its step said 'step 4e-05 x 4' (no units), its threshold and scalar (heights) as if in degrees
    rc, out, err = cli("classify", path, "-o", tmp_path / "both.las", "--ground", "--noise", "--cell", "0.00004", "--window", "0.0002",
                       "--step", "0.00004", "--step-z", "4", "-q")  # fmt: skip
    assert rc == 0, err
    assert " isolated found noise (7; step 4e-05 ° x 4 m, isolated 5); cell 4e-05 °, slope 0.15, window 0.0002, threshold 0.5 m, scalar 1.25 m; " in out


def test_the_parameters_read_the_crs_from_one_header_read(tmp_path, monkeypatch):
    """noise_parameters and ground_parameters read the files' header for their units, then
    again (refuse_files_in_angles) to refuse degrees: two reads of each header, a request each
    for files on a network. Now one read gives both; the refusal names the defaults missing
    (it said "a default step or step_z" with step given)."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    from gigapoint.io import crs
    from gigapoint.survey.ground_raster import ground_parameters
    from gigapoint.survey.noise import noise_parameters

    path = write_degrees_grid(tmp_path / "wgs84.las", 20)
    reads = []
    real_read = crs.read_las_header
    monkeypatch.setattr(crs, "read_las_header",  # (the name io.crs calls: las.read_las_header is bound there at import)
                         lambda f, *a, **k: reads.append(f) or real_read(f, *a, **k))
    for refused in (lambda: noise_parameters([path], step_z=1.0), lambda: ground_parameters([path], window=1.0)):
        with pytest.raises(InputError, match=r"; a default (step|cell) \((4|1) m\) needs metres or feet: "):
            refused()
        assert reads == [path]
        reads.clear()
    assert noise_parameters([path], step=0.00004, step_z=1.0)["units"] == "°" and reads == [path]
