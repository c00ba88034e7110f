"""gigapoint as a notebook (IPython/Jupyter) shows it: errors, images and names."""

from __future__ import annotations

import re

import pytest

import gigapoint as gp


@pytest.fixture(scope="module")
def shell():
    """An in-process IPython shell: what runs a notebook's cells in a Jupyter kernel."""
    interactiveshell = pytest.importorskip("IPython.core.interactiveshell")
    sh = interactiveshell.InteractiveShell.instance()
    sh.run_cell("import gigapoint as gp")
    return sh


def test_a_gigapoint_error_in_a_cell_is_one_line(shell, capsys, tmp_path):
    """A user's mistake (a missing file) showed a 38-line traceback through gigapoint's internals."""
    missing = tmp_path / "missing.laz"
    result = shell.run_cell(f"gp.open({str(missing)!r})")
    assert isinstance(result.error_in_exec, gp.GigapointError)
    assert capsys.readouterr().out.strip().splitlines() == [f"InputError: {missing}: no such file"]
    result = shell.run_cell("gp.render(gp.demo(1000), width=0)")
    assert capsys.readouterr().out.strip().splitlines() == ["CameraError: image width must be an integer in 1..16384, got 0"]
    result = shell.run_cell("1 / 0")  # other errors keep their traceback
    assert "ZeroDivisionError" in capsys.readouterr().out and isinstance(result.error_in_exec, ZeroDivisionError)


def test_a_frame_shows_as_its_image_and_reads_in_one_line(shell):
    """A Frame's repr printed its visibility buffer (18446744073709551615 ...) and the whole cloud;
    a notebook showed no image of it."""
    import io

    import numpy as np
    from PIL import Image

    frame = gp.render_frame(gp.demo(5000), width=320, height=200, background="white")
    assert re.fullmatch(r"Frame\(320x200, 5,000 points drawn, [\d,]+ pixels covered, \w+, [\d.]+ ms\)", repr(frame))
    data, _ = shell.display_formatter.format(frame)
    assert data["text/plain"] == repr(frame)
    shown = np.asarray(Image.open(io.BytesIO(data["image/png"])))
    np.testing.assert_array_equal(shown, frame.image)  # the frame's pixels, exactly


def test_a_cloud_reads_its_bounds_as_its_file_wrote_them(tmp_path):
    """The bounds of autzen read 848935.2000000001 and 62.370000000000005 (float sums), as a
    PointCloud and as an octree; a cloud of one batch '1 batches'."""
    import numpy as np

    cloud = gp.demo(10_000)  # positions at 0.01: its top is 62.37
    gp.convert(gp.demo(10_000, colors="rgba"), tmp_path / "octree")  # (rgba: no warning about approximated colours)
    assert repr(cloud).startswith("PointCloud('demo(10,000)', 10,000 points, 1 batch, bounds [")
    for c in (cloud, gp.open(tmp_path / "octree")):
        numbers = re.findall(r"-?\d+\.\d+", repr(c).split("bounds")[1])
        assert len(numbers) == 6 and all(len(n.split(".")[1]) <= 2 for n in numbers), repr(c)
        np.testing.assert_allclose([float(n) for n in numbers], np.concatenate(c.bounds), atol=0.005)  # within half a step


def test_tab_completion_offers_the_public_names(shell):
    """gp.Vi<tab> offered nothing (Viewer, convert, LiveCloud, ... are imported on first use), gp.<tab> offered 'annotations'."""
    from IPython.core.completer import provisionalcompleter

    assert set(gp.__all__) <= set(dir(gp)) and {"core", "io", "errors"} <= set(dir(gp))
    assert not {"annotations", "choose_threading_layer"} & set(dir(gp))
    with provisionalcompleter():
        for typed, offered in (("gp.Vi", "Viewer"), ("gp.conv", "convert"), ("gp.LiveC", "LiveCloud"), ("gp.render_t", "render_turntable")):
            assert offered in [c.text for c in shell.Completer.completions(typed, len(typed))], typed


def test_a_viewer_screenshot_shows_as_an_image_not_as_bytes(shell):
    """v.screenshot() in a cell printed the repr of its bytes: 470 KB of text for 1280x720."""
    import io

    from PIL import Image

    pytest.importorskip("starlette")
    with gp.Viewer(gp.demo(5000), display=False) as v:
        png = v.screenshot(320, 200)
    assert isinstance(png, bytes) and png[:8] == b"\x89PNG\r\n\x1a\n"  # still bytes, to write to a file
    data, _ = shell.display_formatter.format(png)
    assert data["text/plain"] == f"<PNG, {len(png):,} bytes>"
    assert data["image/png"] == png and Image.open(io.BytesIO(data["image/png"])).size == (320, 200)


def test_running_a_cell_again_closes_the_viewers_its_last_run_made(shell):
    """Each run of `v = gp.Viewer(cloud)` started one more server, each holding its cloud, until the kernel stopped."""
    import httpx

    pytest.importorskip("starlette")
    shell.user_ns["cloud"] = gp.demo(5000)
    shell.run_cell("v = gp.Viewer(cloud, display=False)", cell_id="cell-a")
    first = shell.user_ns["v"]
    shell.run_cell("w = gp.Viewer(cloud, display=False)", cell_id="cell-b")
    shell.run_cell("u = gp.Viewer(cloud, display=False)")  # a frontend that names no cell: kept
    shell.run_cell("v = gp.Viewer(cloud, display=False)", cell_id="cell-a")
    second, other, unnamed = shell.user_ns["v"], shell.user_ns["w"], shell.user_ns["u"]
    try:
        assert first.closed and not second.closed and not other.closed and not unnamed.closed
        with pytest.raises(httpx.TransportError):
            httpx.get(first.url, timeout=2)  # its port is free
        assert httpx.get(second.url, timeout=10).status_code == 200
        shell.run_cell("1", cell_id="cell-b")  # cell b runs again, without a viewer
        assert other.closed and not second.closed
    finally:
        for v in (second, other, unnamed):
            v.close()


def test_a_viewer_closed_is_not_kept_alive_by_its_cell(shell):
    """The note of the cell that made a viewer must not hold it (and its cloud) once it is closed."""
    import gc
    import weakref

    pytest.importorskip("starlette")
    shell.user_ns["cloud"] = gp.demo(5000)
    shell.run_cell("v = gp.Viewer(cloud, display=False); v.close()", cell_id="cell-c")
    gone = weakref.ref(shell.user_ns.pop("v"))
    gc.collect()
    assert gone() is None


def test_a_render_shows_as_its_image_and_reads_in_one_line(shell):
    """gp.render(cloud) as a cell's last line printed its (H, W, 4) array: 8 million numbers for 1920x1080."""
    import io

    import numpy as np
    from PIL import Image

    image = gp.render(gp.demo(5000), width=320, height=200, background="white")
    assert repr(image) == "Image(320x200 RGBA, uint8)"
    data, _ = shell.display_formatter.format(image)
    assert data["text/plain"] == repr(image)
    np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(data["image/png"]))), image)  # its pixels, exactly
    assert repr(image[..., :3]) == "Image(320x200 RGB, uint8)" and repr(image[50:150, :100]) == "Image(100x100 RGBA, uint8)"
    frame = gp.render_frame(gp.demo(5000), width=64, height=48)
    assert repr(frame.image) == "Image(64x48 RGBA, uint8)"  # a frame's image and a stereo pair's too
    assert repr(gp.render(gp.demo(5000), width=64, height=48, stereo="side-by-side")) == "Image(128x48 RGBA, uint8)"


def test_a_render_is_the_array_it_was_to_numpy_pil_and_imageio(tmp_path):
    """Everything an array did with the image gives the same numbers; what is no longer a
    picture (a pixel, a channel, a float array, a sum) is a plain ndarray or a number."""
    import pickle

    import imageio.v3 as iio
    import numpy as np
    from PIL import Image

    image = gp.render(gp.demo(5000), width=80, height=60)
    plain = np.asarray(image)
    assert type(plain) is np.ndarray and np.shares_memory(plain, image)
    for kept in (image.copy(), image[10:20, ::2], image[..., :3], 255 - image, pickle.loads(pickle.dumps(image))):
        assert type(kept) is type(image) and kept.dtype == np.uint8 and kept.ndim == 3
    for result, expected in (
        (image[5, 7], plain[5, 7]),
        (image[..., 0], plain[..., 0]),
        (image / 255.0, plain / 255.0),
        (image == plain[::-1], plain == plain[::-1]),
        (image.max(axis=2), plain.max(axis=2)),
        (image[image > 3], plain[plain > 3]),
    ):
        assert type(result) is np.ndarray
        np.testing.assert_array_equal(result, expected)
    assert type(image.sum()) is np.uint64 and image.sum() == plain.sum() and np.mean(image) == plain.mean()
    assert np.array_equal(image, plain) and np.array_equal(pickle.loads(pickle.dumps(image)), plain)
    assert Image.fromarray(image).tobytes() == Image.fromarray(plain).tobytes()
    iio.imwrite(tmp_path / "a.png", image)
    iio.imwrite(tmp_path / "b.png", plain)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_an_images_methods_give_a_plain_array_where_the_result_is_no_longer_a_picture():
    """astype, reshape, .T, view, ravel... kept the Image class whatever they made: a float or
    flattened image printed as "Image([[[0.5, ...", a (4, 6, 5) transpose as an Image; as slicing a
    pixel already was, what is no longer an (H, W, 3|4) uint8 picture is a plain ndarray."""
    import numpy as np

    image = gp.render(gp.demo(5000), width=6, height=5)
    plain = np.asarray(image)
    for result, expected in (
        (image.astype(np.float32), plain.astype(np.float32)),
        (image.astype(bool), plain.astype(bool)),
        (image.reshape(-1, 4), plain.reshape(-1, 4)),
        (image.T, plain.T),
        (image.swapaxes(0, 2), plain.swapaxes(0, 2)),
        (image.view(np.uint32), plain.view(np.uint32)),
        (image.view(np.int8), plain.view(np.int8)),
        (image.view(np.ndarray), plain),
        (image.ravel(), plain.ravel()),
        (image.flatten(), plain.flatten()),
        (image.argsort(axis=2), plain.argsort(axis=2)),
    ):
        assert type(result) is np.ndarray, result.shape
        np.testing.assert_array_equal(result, expected)
    assert repr(image.astype(np.float32)).startswith("array([[[")
    for kept in (image.astype(np.uint8), image.reshape(6, 5, 4), image.transpose(1, 0, 2), image.view(np.uint8), image.view(), image.repeat(2, axis=0)):
        assert type(kept) is type(image) and repr(kept).startswith("Image(")
    assert repr(image.transpose(1, 0, 2)) == "Image(5x6 RGBA, uint8)"


def test_the_command_line_writes_the_same_bytes_for_an_image_as_for_its_array(tmp_path):
    """The CLI's writer and the viewer's encoder see the Image as the array it views."""
    import numpy as np

    from gigapoint.cli.output import save_image
    from gigapoint.render.frame import encode_image

    image = gp.render(gp.demo(5000), width=80, height=60)
    for suffix in (".png", ".jpg"):
        save_image(image, tmp_path / f"image{suffix}")
        save_image(np.asarray(image).copy(), tmp_path / f"plain{suffix}")
        assert (tmp_path / f"image{suffix}").read_bytes() == (tmp_path / f"plain{suffix}").read_bytes()
    assert encode_image(image, "PNG") == encode_image(np.asarray(image), "PNG") == image._repr_png_()


def test_a_render_as_a_cells_last_line_is_a_png_in_a_jupyter_kernel():
    """What a notebook gets from a real kernel: image/png, and one line of text/plain."""
    import base64
    import io
    from pathlib import Path

    from PIL import Image

    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    src = Path(gp.__file__).parents[1]  # the kernel imports this gigapoint, not an installed one
    code = f"import sys; sys.path.insert(0, {str(src)!r})\nimport gigapoint as gp\ngp.render(gp.demo(2000), width=64, height=48)"
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(code)])
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3").execute()
    (output,) = nb.cells[0].outputs
    assert output.output_type == "execute_result"
    assert output.data["text/plain"] == "Image(64x48 RGBA, uint8)"
    assert Image.open(io.BytesIO(base64.b64decode(output.data["image/png"]))).size == (64, 48)


def test_a_closed_viewer_lets_go_of_the_cloud_it_opened(tmp_path):
    """A closed Viewer of a path, kept by a variable or the notebook's Out[] (``gp.Viewer("big.laz")``
    as a cell's last line), held the cloud it had read until the kernel stopped."""
    import gc
    import weakref

    pytest.importorskip("starlette")
    path = tmp_path / "p.npy"
    np = pytest.importorskip("numpy")
    np.save(path, np.random.default_rng(1).random((2000, 3)))
    v = gp.Viewer(path, display=False)
    opened = weakref.ref(v.cloud)
    v.close()
    gc.collect()
    assert opened() is None and v.cloud is None
    assert repr(v) == f"Viewer('p.npy', {v.url}, closed)" and v.closed
    with pytest.raises(gp.GigapointError, match=r"^Viewer of 'p.npy': closed, its server stopped; open a new Viewer to redraw the cloud$"):
        v.redraw()
    v.close()  # twice: nothing more
    cloud = gp.demo(2000)
    with gp.Viewer(cloud, display=False) as w:
        pass
    assert w.cloud is cloud  # the program's own cloud stays where it was


def test_a_viewers_settings_and_address_are_checked_before_its_points_are_read(tmp_path, monkeypatch):
    """A bad port or settings were said only after the file's points were read (15 s for 5 M points)."""
    pytest.importorskip("starlette")
    read = []
    monkeypatch.setattr(gp, "open", lambda *paths, **_: read.append(paths))
    for bad, problem in (
        ({"settings": {"point_size": 3}}, "settings must be a gigapoint.RenderSettings, got dict"),
        ({"port": -1}, "port must be in 0..65535, got -1"),
        ({"host": ""}, "host must be an address or a host name"),
    ):
        with pytest.raises(gp.GigapointError, match=f"^{re.escape(problem)}"):
            gp.Viewer(tmp_path / "big.laz", display=False, **bad)
    assert read == []
