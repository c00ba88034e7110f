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
