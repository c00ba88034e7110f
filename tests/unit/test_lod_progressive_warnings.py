"""A progressive load's warnings reach the caller as its errors do: kept by the loader, issued
by ``wait`` (and ``close``) in the caller's thread, each once, and listed in ``cloud.warnings``.
They were issued on the loader's thread: Python's warning filters and catches are process-wide,
so a catch around ``wait()`` missed them and they printed at a random moment."""

from __future__ import annotations

import threading
import time
import warnings

import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError


@pytest.fixture
def nan_file(tmp_path):
    path = tmp_path / "some.xyz"
    path.write_text("1 2 3\nnan 2 3\n4 5 6\n")
    return path


def _skipped(path) -> str:
    return f"{path}: skipped 1 invalid point (NaN, inf or beyond ±1e+12)"


def _loaded(cloud):
    """Until the loader is done, without ``wait`` (which issues the warnings)."""
    deadline = time.monotonic() + 60
    while cloud.loading and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not cloud.loading
    return cloud


def test_wait_issues_the_load_s_warning_once_in_the_caller_s_thread(nan_file):
    with warnings.catch_warnings(record=True) as meanwhile:
        warnings.simplefilter("always")
        cloud = _loaded(gp.open(nan_file, progressive=True))
    assert meanwhile == []  # none issued while it loaded (on the loader's thread)
    assert cloud.warnings == (_skipped(nan_file),) and cloud.error is None
    with pytest.warns(GigapointWarning) as caught:
        assert cloud.wait()
    assert [(str(w.message), w.filename) for w in caught] == [(_skipped(nan_file), __file__)]  # at the line that waited
    with warnings.catch_warnings(record=True) as again:
        warnings.simplefilter("always")
        assert cloud.wait()
        cloud.close()
    assert again == [] and cloud.warnings == (_skipped(nan_file),)


def test_a_caller_s_error_filter_applies_at_wait_not_to_the_loader(nan_file):
    """``-W error`` (here a filter) turned the loader's warning into an exception on its thread:
    the load stopped with "loading stopped: ...". Now ``wait`` raises the warning and the load is whole."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", GigapointWarning)
        cloud = _loaded(gp.open(nan_file, progressive=True))
        assert cloud.error is None and cloud.n_points == 2
        with pytest.raises(GigapointWarning, match=r"skipped 1 invalid point \("):
            cloud.wait()
        assert cloud.wait()  # (issued once: the second wait says nothing)
    cloud.close()


def test_close_issues_the_warnings_no_wait_issued(nan_file):
    cloud = _loaded(gp.open(nan_file, progressive=True))
    with pytest.warns(GigapointWarning) as caught:
        cloud.close()
    assert [str(w.message) for w in caught] == [_skipped(nan_file)]


def test_gigapoint_render_prints_the_load_s_warning_once(nan_file, tmp_path, capsys):
    from gigapoint.cli import main

    out = tmp_path / "a.png"
    assert main(["render", str(nan_file), "-o", str(out), "--progressive", "-W", "32", "-H", "24"]) == 0
    err = capsys.readouterr().err
    assert err.count(_skipped(nan_file)) == 1 and f"\nwarning: {_skipped(nan_file)}\n" in "\n" + err, err


@pytest.mark.parametrize("window", [False, True])
def test_gigapoint_view_prints_the_load_s_warning_once(nan_file, capsys, monkeypatch, window):
    """The browser viewer and the native window (whose load's warnings, once kept for ``wait``,
    no one issued: it had no thread reporting the load)."""
    from gigapoint.cli import main
    from gigapoint.viewer import window as native
    from gigapoint.viewer.server import ViewerServer

    def until_reported(*args):  # instead of serving, or a window's loop, until Ctrl+C
        for thread in threading.enumerate():
            if thread.name == "gigapoint-load-report":
                thread.join(60)

    monkeypatch.setattr(ViewerServer, "serve_forever", until_reported)
    monkeypatch.setattr(native, "check_display", lambda: None)
    monkeypatch.setattr(native, "open_window", lambda cloud, settings=None: None)
    monkeypatch.setattr(native, "run_loop", until_reported)
    assert main(["view", str(nan_file), "--progressive", "--no-browser", *(["--window"] if window else [])]) == 0
    err = capsys.readouterr().err
    assert err.count(_skipped(nan_file)) == 1 and f"\nwarning: {_skipped(nan_file)}\n" in "\n" + err, err


@pytest.mark.parametrize("name, text", [
    ("a.xyz", "1 2 3\n4 5 6\n"),
    ("a.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n"),
    ("lists.ply", ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                   "property list uchar int tags\nend_header\n1 2 3 0\n4 5 6 1 7\n")),  # (plyfile read it, its empty list in a catch_warnings)
])  # fmt: skip
def test_reading_text_on_the_decoder_s_thread_leaves_a_caller_s_catch_as_it_was(tmp_path, monkeypatch, name, text):
    """The text and ASCII PLY readers wrapped loadtxt in ``catch_warnings`` (its "no data"
    warning) on the decoder's thread: a caller's catch entered meanwhile had its recording undone
    when the reader's ended (here: made to end inside it), and its filters left behind."""
    import numpy as np

    from gigapoint.io import read_chunks

    path = tmp_path / name
    path.write_text(text)
    inside, go, loadtxt = threading.Event(), threading.Event(), np.loadtxt

    def held(*args, **kw):  # the reader's loadtxt waits until the caller's catch is entered
        inside.set()
        go.wait(10)
        return loadtxt(*args, **kw)

    monkeypatch.setattr(np, "loadtxt", held)
    got = []
    reader = threading.Thread(target=lambda: got.extend(read_chunks(path, 1_000)))
    filters = list(warnings.filters)
    reader.start()
    assert inside.wait(10)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        go.set()
        reader.join(10)
        warnings.warn("the caller's", UserWarning)
    assert [str(w.message) for w in seen] == ["the caller's"] and warnings.filters == filters
    assert sum(len(c) for c in got) == 2


def test_a_chunk_of_comments_only_reads_on_without_a_word(tmp_path):
    from gigapoint.io import read_chunks

    path = tmp_path / "c.xyz"
    path.write_text("1 2 3\n# a\n# b\n\n4 5 6\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = [c.xyz.tolist() for c in read_chunks(path, 2)]
    assert got == [[[1.0, 2.0, 3.0]], [[4.0, 5.0, 6.0]]]


def test_the_viewer_s_line_on_a_finished_load_says_its_warnings(nan_file, tmp_path):
    """The HUD's line on a finished load said how many points, not that some were skipped."""
    from gigapoint.viewer.watch import load_note

    cloud = _loaded(gp.open(nan_file, progressive=True))
    assert load_note(cloud, 0.0).endswith(f" s; warning: {_skipped(nan_file)}")
    with pytest.warns(GigapointWarning):
        cloud.close()
    other = tmp_path / "other.xyz"
    other.write_text("7 8 9 1\n")  # an intensity the first file has not
    two = _loaded(gp.open(nan_file, other, progressive=True))
    dropped = "2 files: attribute(s) intensity not in every file: left out (only those all the files have are kept)"
    assert len(two.warnings) == 2 and load_note(two, 0.0).endswith(f" s; warning: {dropped} (and 1 more)")
    with pytest.warns(GigapointWarning):
        two.close()



def test_a_library_s_warning_on_the_loader_s_thread_is_kept_and_issued_once_by_wait(tmp_path):
    """numpy's RuntimeWarning on the loader's thread (a float64 attribute of 1e300 packed into
    float32 as the load ends) went through Python's machinery from that thread: it printed at any
    moment, and a ``pytest.warns`` around ``wait()`` never saw it. Now kept with the load's own,
    after them, each once with its category, and issued by ``wait`` at the caller's line."""
    import numpy as np

    nan = tmp_path / "nan.xyz"
    nan.write_text("1 2 3 0\nnan 2 3 0\n")  # x y z intensity: one invalid point, gigapoint's warning
    loud = tmp_path / "loud.npy"
    np.save(loud, np.column_stack([np.arange(12.0).reshape(4, 3), [1.0, 1e300, 1e300, 2.0]]))
    overflow = "overflow encountered in cast"  # numpy's, for each of the two
    with warnings.catch_warnings(record=True) as meanwhile:
        warnings.simplefilter("always")  # numpy's warning shown however often it came
        cloud = _loaded(gp.open(nan, loud, progressive=True))
    assert meanwhile == []  # none issued on the load's threads
    skipped = f"{nan}, {loud}: skipped 1 invalid point (NaN, inf or beyond ±1e+12)"
    assert cloud.warnings == (skipped, overflow)
    with pytest.warns(Warning) as caught:
        assert cloud.wait()
    assert [(str(w.message), w.category, w.filename) for w in caught] == [
        (skipped, GigapointWarning, __file__), (overflow, RuntimeWarning, __file__)]  # fmt: skip
    cloud.close()


def test_a_library_s_warning_made_an_error_by_the_caller_ends_the_load_with_it(tmp_path):
    """With ``-W error`` (or pytest's filterwarnings=error) numpy's warning is raised on the
    loader's thread as the load ends (``trim``), where nothing caught it: ``wait()`` waited for
    good. Now the load ends, and ``wait`` raises it as the load's one-line error."""
    import numpy as np

    loud = tmp_path / "loud.npy"
    np.save(loud, np.column_stack([np.arange(12.0).reshape(4, 3), [1.0, 1e300, 1e300, 2.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        cloud = gp.open(loud, progressive=True)
        with pytest.raises(InputError) as err:
            cloud.wait(timeout=60)
        assert str(err.value) == f"{loud}: loading stopped: overflow encountered in cast"
        assert cloud.loading is False
    cloud.close()
