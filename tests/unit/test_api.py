"""The public names of the gigapoint package resolve to the documented functions."""

import inspect
import os
import re

import numpy as np
import pytest

import gigapoint as gp


def test_public_names_resolve():
    for name in gp.__all__:
        assert getattr(gp, name) is not None, name
    from gigapoint.lod.convert import convert
    from gigapoint.render.normals import estimate_normals
    from gigapoint.render.video import render_flythrough, render_turntable

    assert gp.convert is convert and gp.estimate_normals is estimate_normals
    assert gp.render_turntable is render_turntable and gp.render_flythrough is render_flythrough
    assert "out" in inspect.signature(gp.convert).parameters


def test_unknown_name_is_an_attribute_error():
    try:
        gp.no_such_thing  # noqa: B018
    except AttributeError as exc:
        assert "no_such_thing" in str(exc)
    else:
        raise AssertionError("expected AttributeError")


def test_estimate_normals_through_the_package_on_a_plane():
    import numpy as np

    rng = np.random.default_rng(1)
    xyz = np.column_stack([rng.uniform(0, 10, 4000), rng.uniform(0, 10, 4000), np.zeros(4000)])
    cloud = gp.from_arrays(xyz)
    normals, radii = gp.estimate_normals(cloud, store=False)
    assert normals.shape == (4000, 3) and np.all(normals[:, 2] > 0.999) and np.all(radii > 0)


def test_render_without_a_camera_frames_the_cloud_as_fit_cloud_does():
    """``gp.render(cloud)`` (and ``render_frame``) take ``Camera.fit_cloud(cloud)``: the same
    pixels as that camera given, the cloud in view; a progressive cloud is framed as it is now."""
    import numpy as np

    rng = np.random.default_rng(2)
    xyz = rng.uniform(0, 100, (20_000, 3)) * (1, 1, 0.1) + (5e5, 4e6, 30)  # UTM-sized, flat
    cloud = gp.from_arrays(xyz)
    image = gp.render(cloud, size_mode="fixed")
    want = gp.render(cloud, gp.Camera.fit_cloud(cloud), size_mode="fixed")
    assert image.shape == (1080, 1920, 4)
    np.testing.assert_array_equal(image, want)
    covered = gp.render_frame(cloud).visibility != np.uint64(0xFFFFFFFFFFFFFFFF)
    assert covered.sum() > 10_000  # the points are in view, not a background
    from gigapoint.lod.progressive import ProgressiveOctree

    grown = ProgressiveOctree("grown")
    grown.add(xyz[:10_000])
    part = gp.render(grown, size_mode="fixed")
    np.testing.assert_array_equal(part, gp.render(grown, gp.Camera.fit_cloud(grown), size_mode="fixed"))
    assert (part[..., :3] != image[0, 0, :3]).any(axis=-1).sum() > 5_000


def test_render_takes_an_image_size_with_or_without_a_camera():
    """``gp.render(cloud, width=800, height=600)`` was "unknown render setting(s): height, width":
    the fitted camera takes the size (the same pixels as ``fit_cloud`` at that size), a given
    camera is drawn at it; a size it cannot be is a CameraError (Camera.fit: a TypeError for 'a')."""
    import numpy as np
    import pytest

    from gigapoint.errors import CameraError

    cloud = gp.demo(20_000)
    small = gp.render(cloud, width=320, height=200, size_mode="fixed")
    np.testing.assert_array_equal(small, gp.render(cloud, gp.Camera.fit_cloud(cloud, width=320, height=200), size_mode="fixed"))
    cam = gp.Camera.fit_cloud(cloud, width=640, height=400)
    np.testing.assert_array_equal(gp.render(cloud, cam, height=100, size_mode="fixed"), gp.render(cloud, cam.with_size(160, 100), size_mode="fixed"))
    for bad in (0, 2.5, "a", 10**6, True):
        with pytest.raises(CameraError, match=rf"^image width must be an integer in 1\.\.16384, got {re.escape(repr(bad))}$"):
            gp.render(cloud, width=bad)
        with pytest.raises(CameraError, match="^image height must be an integer"):
            gp.Camera.fit(cloud.bounds, height=bad)


def test_one_side_of_the_image_size_alone_keeps_the_aspect_in_render_and_render_frame():
    """``gp.render(cloud, width=33)`` was 33x1080 and ``render_frame(cloud, width=33)`` "unknown
    render setting(s): width": the side not given follows the camera's aspect (the fitted one's
    16:9), to the nearest pixel (half up), at least 1; render and render_frame draw the same."""
    import numpy as np
    import pytest

    from gigapoint.errors import CameraError

    cloud = gp.demo(2_000)
    for size, shape in (({"width": 33}, (19, 33)), ({"height": 90}, (90, 160)), ({"width": 8}, (5, 8)), ({"width": 1}, (1, 1)),
                        ({"height": 1}, (1, 2)), ({"width": 48, "height": 48}, (48, 48))):  # fmt: skip
        image = gp.render(cloud, size_mode="fixed", **size)
        assert image.shape == (*shape, 4), size
        np.testing.assert_array_equal(gp.render_frame(cloud, size_mode="fixed", **size).image, image)
    cam = gp.Camera.fit_cloud(cloud, width=640, height=400)  # a given camera: its own aspect
    assert gp.render_frame(cloud, cam, width=64).image.shape == (40, 64, 4)
    assert (cam.width, cam.height) == (640, 400)
    for call in (gp.render, gp.render_frame):
        with pytest.raises(CameraError, match=r"^image width must be an integer in 1\.\.16384, got 0$"):
            call(cloud, width=0)
        with pytest.raises(CameraError, match=r"^image width would be 29127 \(height 16384 at 1920x1080's aspect\), over 16384: give both sides$"):
            call(cloud, height=16384)


def test_open_names_an_unknown_option_and_what_it_takes(tmp_path):
    """``gp.open(path, foo=1)`` was a TypeError naming the internal ``open_cloud()``."""
    import numpy as np
    import pytest

    from gigapoint.errors import InputError

    np.save(tmp_path / "p.npy", np.random.default_rng(1).random((20, 3)))
    with pytest.raises(InputError, match=r"^open: unknown option\(s\) bar, foo; it takes chunk_size, .*colors, chunked, recursive=True, progressive=True"):
        gp.open(tmp_path / "p.npy", foo=1, bar=2)
    assert gp.open(tmp_path / "p.npy", chunk_size=7, colors="rgba").n_points == 20


def test_settings_that_are_not_render_settings_are_one_line_errors(tmp_path):
    """A dict of settings was an AttributeError ('dict' object has no attribute 'supersample') deep
    in render, the turntable, the viewer; None still means the defaults."""
    import pytest

    import gigapoint as gp
    from gigapoint.render.settings import SettingsError

    cloud = gp.demo(2_000)
    camera = gp.Camera.fit(cloud.bounds, width=32, height=24)
    wrong = "settings must be a gigapoint.RenderSettings, got dict"
    for call in (
        lambda: gp.render(cloud, camera, settings={"point_size": 3}),
        lambda: gp.render(cloud, camera, settings={"point_size": 3}, point_size=2),
        lambda: gp.render_frame(cloud, camera, {"point_size": 3}),
        lambda: gp.render_turntable(cloud, 2, tmp_path / "t.gif", settings={"point_size": 3}, width=32, height=24),
        lambda: gp.Viewer(cloud, settings={"point_size": 3}, display=False),
    ):
        with pytest.raises(SettingsError, match=wrong):
            call()
    assert not list(tmp_path.iterdir())
    assert gp.render(cloud, camera, settings=None).shape == (24, 32, 4)
    np.testing.assert_array_equal(gp.render(cloud, camera, settings=None), gp.render(cloud, camera, gp.RenderSettings()))


def test_render_frame_takes_settings_as_keywords_as_render_does():
    """gp.render_frame(cloud, camera, point_size=3) was a TypeError (render takes the keywords):
    now the frame of those settings; an unknown one is render's one-line error."""
    import pytest

    import gigapoint as gp
    from gigapoint.render.settings import SettingsError

    cloud = gp.demo(5_000)
    camera = gp.Camera.fit(cloud.bounds, width=48, height=32)
    by_keyword = gp.render_frame(cloud, camera, point_size=3, size_mode="fixed")
    given = gp.render_frame(cloud, camera, gp.RenderSettings(point_size=3, size_mode="fixed"))
    np.testing.assert_array_equal(by_keyword.image, given.image)
    np.testing.assert_array_equal(by_keyword.image, gp.render(cloud, camera, point_size=3, size_mode="fixed"))
    assert not np.array_equal(by_keyword.image, gp.render_frame(cloud, camera, size_mode="fixed").image)  # (the size took)
    with pytest.raises(SettingsError, match="unknown render setting"):
        gp.render_frame(cloud, camera, pointsize=3)


def test_render_keywords_draw_what_their_command_line_options_draw():
    """gp.render(c, point_world_size=2) drew 1-px points and gp.render(c, color_attribute=...)
    the rgb colours: each means what its option means (--point-world-size: attenuated, at most
    16 px; --color-attribute: that attribute's colours)."""
    from gigapoint.cli.settings_opts import settings_from_options

    cloud = gp.demo(5_000)
    camera = gp.Camera.fit(cloud.bounds, width=96, height=64)
    as_option = settings_from_options(gp.RenderSettings, {"point_world_size": 60.0}, {"point_world_size"})
    big = gp.render(cloud, camera, point_world_size=60.0)  # (~15 m a pixel)
    np.testing.assert_array_equal(big, gp.render(cloud, camera, as_option))
    assert not np.array_equal(big, gp.render(cloud, camera, size_mode="fixed"))  # (wider than 1 px)
    name = next(iter(cloud.attributes))
    by_attribute = gp.render(cloud, camera, color_attribute=name)
    np.testing.assert_array_equal(by_attribute, gp.render(cloud, camera, color_mode="attribute", color_attribute=name))
    assert not np.array_equal(by_attribute, gp.render(cloud, camera))


def test_open_takes_true_or_false_for_its_switches(tmp_path):
    """progressive="no" and chunked="no" were taken as true; so was overwrite="no" in convert,
    videos and live recordings and snapshots, which replaced what the user had."""
    import pytest

    from gigapoint.errors import InputError

    np.save(tmp_path / "p.npy", np.random.default_rng(0).random((100, 3)))
    with pytest.raises(InputError, match=r"^open: progressive must be True or False, got 'no'$"):
        gp.open(tmp_path / "p.npy", progressive="no")
    with pytest.raises(InputError, match=r"^open: chunked must be True or False or None, got 'no'$"):
        gp.open(tmp_path / "p.npy", chunked="no")
    assert gp.open(tmp_path / "p.npy", chunked=False).n_points == gp.open(tmp_path / "p.npy", progressive=False).n_points == 100
    assert gp.open(tmp_path / "p.npy", chunked=np.True_).n_points == 100
    for kw, problem in (  # progress="no" showed a bar; name=5 named the cloud 5; chunk_size=True read a point a chunk, 2.5 read 2
        ({"progress": "no"}, "open: progress must be True or False, got 'no'"),
        ({"name": 5}, "open: name must be a string, got 5"),
        ({"chunk_size": True}, "open: chunk_size must be an integer >= 1, got True"),
        ({"chunk_size": 2.5}, "open: chunk_size must be an integer >= 1, got 2.5"),
    ):
        with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
            gp.open(tmp_path / "p.npy", **kw)
    assert gp.open(tmp_path / "p.npy", chunk_size=np.int64(30), name="p").n_points == 100
    gp.convert([tmp_path / "p.npy"], tmp_path / "octree")
    (tmp_path / "turn.gif").write_bytes(b"mine")
    (tmp_path / "mine.laz").write_bytes(b"mine")
    live = gp.LiveCloud()
    live.push(np.random.default_rng(1).random((50, 3)))
    live.snapshot()
    for call, where in (
        (lambda: gp.convert([tmp_path / "p.npy"], tmp_path / "octree", overwrite="no"), "convert"),
        (lambda: gp.render_turntable(gp.demo(1_000), 2, tmp_path / "turn.gif", width=32, height=24, overwrite="no"), "video"),
        (lambda: live.record(tmp_path / "rec", overwrite="false"), "live: record"),
        (lambda: live.save(tmp_path / "octree", overwrite="no"), "live: save"),
        # (a progressive cloud's plain file: its save took "no" as true and replaced it)
        (lambda: _loaded(gp.open(tmp_path / "p.npy", progressive=True)).save(tmp_path / "mine.laz", overwrite="no"), re.escape(str(tmp_path / "mine.laz"))),
    ):
        with pytest.raises(InputError, match=rf"^{where}: overwrite must be True or False, got '(no|false)'$"):
            call()
    assert (tmp_path / "turn.gif").read_bytes() == b"mine" and gp.open(tmp_path / "octree").n_points == 100
    assert (tmp_path / "mine.laz").read_bytes() == b"mine"


def _loaded(cloud):
    """``cloud`` once its loader has read everything."""
    assert cloud.wait()
    return cloud


def test_the_demo_refuses_a_seed_or_scale_it_cannot_use_in_one_line():
    """A string seed was numba's TypingError from the generator's kernel, 2**70 an OverflowError;
    scale=0 said "no valid points (1,000 invalid points)", scale=-1 a ValueError of the layout."""
    import pytest

    from gigapoint.errors import InputError

    for kw, problem in (
        ({"seed": "a"}, r"seed must be an integer from -9,223,372,036,854,775,807 to 9,223,372,036,854,775,807, got 'a'"),
        ({"seed": 2**70}, "seed must be an integer from"),
        ({"seed": 2.5}, "seed must be an integer from"),
        ({"scale": 0}, r"scale must be None \(float positions\) or a grid step between 1e-6 and 1000 metres, got 0$"),
        ({"scale": -1}, "scale must be None"),
        ({"scale": float("nan")}, "scale must be None"),
        ({"scale": "0.01"}, "scale must be None"),
    ):
        with pytest.raises(InputError, match=rf"^demo: {problem}"):
            gp.demo(1_000, **kw)
    assert gp.demo(1_000, seed=-1, scale=None).n_points == gp.demo(1_000, scale=0.001).n_points == 1_000
    with pytest.raises(InputError, match=r"^demo: n_points must be an integer >= 1, got 0$"):  # "no valid points"
        gp.demo(0)


def test_from_arrays_judges_colours_as_a_file_of_them_is_read(tmp_path):
    """Float colours of 0..255 given to from_arrays were all white (taken as 0..1 and clipped),
    the same array saved as .npy read right; a scalar attribute (intensity=5) was a TypeError;
    name=5 was taken. Colours now go through the readers' ColorScaler (0..1, 0..255, 0..65535)."""
    import numpy as np
    import pytest

    from gigapoint.errors import InputError

    rng = np.random.default_rng(4)
    xyz = rng.random((500, 3))
    for rgb in (rng.uniform(0, 255, (500, 3)), rng.random((500, 3)), rng.integers(0, 65535, (500, 3)).astype(np.uint16), rng.uniform(0, 65535, (500, 3))):
        np.save(tmp_path / "p.npy", np.column_stack([xyz, rgb]))
        from_file = gp.open(tmp_path / "p.npy")
        np.testing.assert_array_equal(gp.from_arrays(xyz, rgb=rgb, colors="rgba").rgba, gp.open(tmp_path / "p.npy", colors="rgba").rgba)
        assert from_file.n_points == 500
    assert 100 < gp.from_arrays(xyz, rgb=np.full((500, 3), 128.0)).rgba[:, :3].mean() < 130  # not 255
    live = gp.LiveCloud()
    live.push(xyz, np.full((500, 3), 128.0))  # a frame's colours alike
    assert (live.frame_points()[1][:, :3] == 128).all()
    for kw, problem in (
        ({"intensity": 5}, "arrays: attribute 'intensity' is one value (5), not one per point"),
        ({"name": 5}, "from_arrays: name must be a string, got 5"),
        # a dict as an attribute printed its whole repr over many lines
        ({"attributes": {"intensity": np.arange(500)}}, ("arrays: attribute 'attributes' is a dict; give attributes as keywords: "
         "from_arrays(xyz, rgb, intensity=...) or **attributes")),
        ({"label": "roof " * 100}, "arrays: attribute 'label' is one value ('roof roof roof roof roof roof roof roof roof roof roof roof...), not one per point"),
    ):
        with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
            gp.from_arrays(xyz, **kw)


@pytest.mark.timeout(60)
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_named_pipe_is_refused_at_once_not_read_for_good(tmp_path, capsys):
    """A FIFO named x.las hung gp.open, `info`, `render` and `convert`: the COPC sniff read its
    head, waiting for a writer for good, before the check that it is a regular file."""
    from gigapoint.cli import main

    pipe = tmp_path / "pipe.las"
    os.mkfifo(pipe)
    for kw in ({}, {"progressive": True}):
        with pytest.raises(gp.GigapointError, match=f"^{re.escape(str(pipe))}: is not a regular file$"):
            gp.open(pipe, **kw)
    for args in (["info", str(pipe)], ["render", str(pipe), "-o", str(tmp_path / "x.png")], ["convert", str(pipe), "-o", str(tmp_path / "o")]):
        assert main(args) == 1, args
        assert "pipe.las: is not a regular file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.las"]


def test_the_demo_and_render_take_true_or_false_for_their_switches():
    """gp.demo(progressive="yes") loaded progressively, attributes="no" kept them and
    chunked="x" built in bounded memory; gp.render(return_stats="no") gave the stats too."""
    for kw, problem in (
        ({"progressive": "yes"}, "progressive must be True or False, got 'yes'"),
        ({"attributes": "no"}, "attributes must be True or False, got 'no'"),
        ({"chunked": "x"}, "chunked must be True or False or None, got 'x'"),
    ):
        with pytest.raises(gp.GigapointError, match=f"^demo: {re.escape(problem)}$"):
            gp.demo(1_000, **kw)
    cloud = gp.demo(1_000, chunked=None, attributes=np.bool_(False))
    assert list(cloud.attribute_names) == []
    with pytest.raises(gp.GigapointError, match=r"^render: return_stats must be True or False, got 'no'$"):
        gp.render(cloud, return_stats="no", width=32, height=24)
    image, stats = gp.render(cloud, return_stats=True, width=32, height=24)
    assert image.shape == (24, 32, 4) and stats.points_total == 1_000
