"""gigapoint.atomic: whole-file writes that never leave a torn or half-written file."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from gigapoint import atomic
from gigapoint.atomic import atomic_bytes, atomic_json, atomic_npy, atomic_open, atomic_write, start_writeback, temp_files


def test_writes_replace_the_file_and_leave_nothing_else(tmp_path):
    path = tmp_path / "a.bin"
    atomic_bytes(path, b"old")
    atomic_bytes(path, b"new content")
    assert path.read_bytes() == b"new content"
    atomic_json(tmp_path / "m.json", {"a": [1, 2]}, indent="\t")
    assert (tmp_path / "m.json").read_text() == json.dumps({"a": [1, 2]}, indent="\t")
    arr = np.arange(12, dtype=np.uint32).reshape(3, 4)
    atomic_npy(tmp_path / "x.npy", arr)
    np.testing.assert_array_equal(np.load(tmp_path / "x.npy"), arr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "m.json", "x.npy"]


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_failed_write_keeps_the_old_file_and_removes_its_temporary(tmp_path, error):
    path = tmp_path / "image.png"
    path.write_bytes(b"the old image")
    seen = []

    def write(tmp):
        seen.append(tmp)
        tmp.write_bytes(b"half an ima")
        raise error

    with pytest.raises(type(error)):
        atomic_write(path, write)
    assert path.read_bytes() == b"the old image"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["image.png"] and not seen[0].exists()


def test_a_write_error_without_a_file_name_gets_the_outputs(tmp_path):
    """numpy's "Not enough free space to write ..." (a full disk) is an OSError naming no file:
    the CLI said "error: Not enough free space ..." without saying which output."""
    path = tmp_path / "depth.npy"

    def write(tmp):
        raise OSError("Not enough free space to write 48000000 bytes after offset 128")

    with pytest.raises(OSError) as e:
        atomic_write(path, write)
    assert e.value.filename == str(path) and e.value.strerror == "Not enough free space to write 48000000 bytes after offset 128"
    with pytest.raises(OSError) as e, atomic_open(tmp_path / "x.bin"):
        raise OSError(28, "No space left on device")
    assert e.value.filename == str(tmp_path / "x.bin") and e.value.errno == 28
    assert not list(tmp_path.iterdir())
    with pytest.raises(FileNotFoundError) as e:  # one that names a file keeps its name
        atomic_write(path, lambda tmp: (tmp_path / "nowhere" / "f").read_bytes())
    assert e.value.filename == str(tmp_path / "nowhere" / "f")


@pytest.mark.parametrize("kind", ["atomic_write", "atomic_npy", "atomic_bytes"])
def test_a_folder_that_takes_no_new_file_names_the_output_not_its_temporary(tmp_path, monkeypatch, kind):
    """A read-only (or full) file system refuses the temporary file itself: the CLI said
    "error: /out/.x.png.3e4ec217.tmp.png: Read-only file system", a name the user never gave."""
    import errno

    real_open = os.open

    def read_only(path, flags, mode=0o777, **kw):
        if flags & os.O_CREAT:
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, flags, mode, **kw)

    monkeypatch.setattr(os, "open", read_only)
    out = tmp_path / "x.png"
    write = {"atomic_write": lambda: atomic_write(out, lambda tmp: None), "atomic_npy": lambda: atomic_npy(out, np.zeros(3)),
             "atomic_bytes": lambda: atomic_bytes(out, b"png")}[kind]  # fmt: skip
    with pytest.raises(OSError) as e:
        write()
    assert e.value.filename == str(out) and e.value.errno == errno.EROFS


def test_the_temporary_file_is_new_hidden_beside_and_keeps_the_suffix(tmp_path):
    names = []

    def write(tmp):
        assert tmp.parent == tmp_path and tmp.exists() and tmp.stat().st_size == 0
        names.append(tmp.name)
        tmp.write_bytes(b"x")

    atomic_write(tmp_path / "video.mp4", write)
    atomic_write(tmp_path / "video.mp4", write)
    assert all(n.startswith(".video.mp4.") and n.endswith(".tmp.mp4") for n in names)
    assert names[0] != names[1]  # two writers of one file never share a temporary file


def test_permissions_follow_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        atomic_bytes(tmp_path / "a", b"x")
        os.umask(0o022)
        atomic_bytes(tmp_path / "b", b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a").stat().st_mode) == 0o640
    assert stat.S_IMODE((tmp_path / "b").stat().st_mode) == 0o644


def test_durable_writes_fsync_before_the_rename(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (events.append("fsync"), real_fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (events.append("replace"), real_replace(a, b))[1])
    atomic_bytes(tmp_path / "fast", b"x")
    assert events == ["replace"]
    events.clear()
    atomic_json(tmp_path / "state.json", {"phase": "read"}, durable=True)
    assert events == ["fsync", "replace"]


def test_temp_files_finds_what_a_killed_writer_left(tmp_path):
    names = []
    atomic_write(tmp_path / "keys.npy", lambda tmp: (names.append(tmp.name), tmp.write_bytes(b"x")))
    atomic_write(tmp_path / "state", lambda tmp: (names.append(tmp.name), tmp.write_bytes(b"x")))
    for name in names:  # as a SIGKILL between creating and renaming would leave them
        (tmp_path / name).write_bytes(b"partial")
    for other in ("keys.tmp", ".hidden", "a.tmp.npy", ".keys.npy.zzzzzzzz.tmp.npy"):
        (tmp_path / other).write_bytes(b"y")
    assert sorted(p.name for p in temp_files(tmp_path)) == sorted(names)


def test_atomic_open_keeps_the_old_file_when_the_block_fails(tmp_path):
    path = tmp_path / "state.json"
    path.write_text("old")
    with pytest.raises(RuntimeError, match="killed"), atomic_open(path) as f:
        f.write(b"half a sta")
        raise RuntimeError("killed")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]
    with atomic_open(path, durable=True) as f:
        f.write(b"new")
    assert path.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


@pytest.mark.parametrize(
    "array",
    [
        np.arange(1 << 20, dtype=np.uint64),  # 8 MB: through a memory map
        np.zeros((1 << 18, 3)),
        np.zeros(1 << 19, dtype=[("a", "<u4"), ("b", "<f8")]),
        np.arange(3 << 20).reshape(-1, 3)[:, :2],  # not contiguous: np.save
        np.asfortranarray(np.ones((1 << 10, 1 << 10))),  # Fortran order: np.save
        np.arange(10, dtype=np.int16),
    ],
)
def test_atomic_npy_writes_the_bytes_np_save_writes(tmp_path, array):
    import io

    atomic_npy(tmp_path / "a.npy", array)
    saved = io.BytesIO()
    np.save(saved, array)
    assert (tmp_path / "a.npy").read_bytes() == saved.getvalue()
    assert [p.name for p in tmp_path.iterdir()] == ["a.npy"]


def test_a_full_disk_before_a_mapped_write_is_an_oserror_naming_the_file(tmp_path, monkeypatch):
    """Files filled through memory maps have their space reserved first (posix_fallocate): a full
    disk raises here, naming the file, where a store into the map would kill the process (SIGBUS).
    A large atomic_npy keeps the old file and leaves no temporary."""
    import errno

    from gigapoint.atomic import mapped_npy

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    with pytest.raises(OSError) as err:
        mapped_npy(tmp_path / "m.npy", np.uint64, (1000,))
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(tmp_path / "m.npy")
    atomic_bytes(tmp_path / "x.npy", b"old")
    with pytest.raises(OSError, match="No space left") as err:
        atomic_npy(tmp_path / "x.npy", np.zeros(1 << 20))
    assert err.value.filename == str(tmp_path / "x.npy")
    assert (tmp_path / "x.npy").read_bytes() == b"old" and not list(temp_files(tmp_path))


def test_a_short_write_says_how_much_was_written():
    from gigapoint.atomic import _name_the_file

    exc = OSError("26979 requested and 13296 written")  # numpy's tofile on a full disk: no errno, no file
    _name_the_file(exc, "/out/carry.xyz.npy")
    assert str(exc) == "[Errno None] only 13296 of 26979 bytes written (is the disk full?): '/out/carry.xyz.npy'"


@pytest.mark.parametrize("libc", [True, False])
def test_start_writeback_changes_no_byte_and_needs_no_libc(tmp_path, monkeypatch, libc):
    """Writeback started on a range of a file written through a memory map (Linux's
    sync_file_range; nothing where there is none) leaves every byte as written, and a later
    fsync makes it durable as before."""
    if not libc:
        monkeypatch.setattr(atomic, "_sync_file_range", lambda: None)
    elif atomic._sync_file_range() is None:
        pytest.skip("no sync_file_range here")
    data = np.random.default_rng(0).integers(0, 255, 3 << 20, dtype=np.uint8)
    path = tmp_path / "a.bin"
    path.write_bytes(b"\0" * len(data))
    mapped = np.memmap(path, np.uint8, mode="r+")
    mapped[:] = data
    del mapped
    start_writeback(path, 4096, 2 << 20)
    start_writeback(path, 0, 0)
    atomic.fsync_file(path)
    assert np.array_equal(np.fromfile(path, np.uint8), data)


def test_outputs_through_a_link_to_nothing_or_a_missing_folders_dotdot_are_refused_before_any_work(tmp_path, cli, autzen_path):
    """A link to a missing folder was stepped over as missing: every output checked fine, then
    mkdir said "dang: File exists" once the render, the conversion or the tiling was done.
    'new/../x.png' (new missing) made new/ and wrote x.png beside it, new/ left empty."""
    from gigapoint.atomic import folder_refusal

    (tmp_path / "dang").symlink_to(tmp_path / "nowhere" / "dir")
    assert folder_refusal(tmp_path / "dang") == f"{tmp_path / 'dang'} is a link to a missing folder ({tmp_path / 'nowhere' / 'dir'})"
    assert folder_refusal(tmp_path / "dang" / "sub") == folder_refusal(tmp_path / "dang")
    assert folder_refusal(tmp_path / "new" / "..") == "'..' after a folder that does not exist"
    (tmp_path / "real").mkdir()
    (tmp_path / "good").symlink_to(tmp_path / "real")
    assert folder_refusal(tmp_path / "sub" / "new") is None and folder_refusal(tmp_path / "good" / ".." / "new") is None  # (.. of a folder there: the OS's)
    before = sorted(p.name for p in tmp_path.iterdir())
    for out in (tmp_path / "dang" / "x.png", tmp_path / "new" / ".." / "x.png"):
        rc, _, err = cli("render", autzen_path, "-o", out, "--width", "64", "--height", "48")
        assert rc == 1 and err == f"error: {out}: {folder_refusal(out.parent)}\n"
    for out in (tmp_path / "dang" / "x.laz", tmp_path / "new" / ".." / "x.laz"):
        rc, _, err = cli("convert", autzen_path, "-o", out)
        assert rc == 1 and err == f"error: {out}: {folder_refusal(out.parent)}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_images_videos_and_point_files_refuse_their_outputs_through_one_check_in_their_own_words(tmp_path):
    """image_files.check_output, video's path check and io.write.check_point_file_output each
    wrote out the same checks (a folder there, an existing file, the folders on its way);
    ``atomic.output_file_refusal`` says them once, each caller naming its own kind of file."""
    from gigapoint.errors import GigapointError, InputError
    from gigapoint.io.write import check_point_file_output
    from gigapoint.render.image_files import check_output
    from gigapoint.render.video import check_turntable

    (tmp_path / "old.png").write_bytes(b"x")
    (tmp_path / "dir.mp4").mkdir()
    (tmp_path / "dir.laz").mkdir()
    (tmp_path / "clip").mkdir()
    (tmp_path / "afile").write_bytes(b"x")
    refusal = atomic.output_file_refusal
    assert refusal(tmp_path / "old.png", False, "an output file") == "already exists; pass overwrite=True to replace it"
    assert refusal(tmp_path / "old.png", True, "an output file") is None
    assert refusal(tmp_path / "dir.mp4", True, "a video file") == "is a directory, not a video file"
    assert refusal(tmp_path / "afile" / "x.png", False, "an output file") == f"{tmp_path / 'afile'} is a file, not a folder"
    assert refusal(tmp_path / "new" / "x.png", False, "an output file", {".png"}) is None  # (missing folders are made as it is written)
    assert refusal(tmp_path / "x.PNG", False, "an output file", {".png", ".jpg"}) is None
    assert refusal(tmp_path / "x.gif", False, "an output file", {".png", ".jpg"}) == "unsupported output type '.gif'; use one of .jpg, .png"
    assert refusal(tmp_path / "old.png", False, "an output file", {".jpg"}, "image") == "unsupported image type '.png'; use one of .jpg"
    assert refusal(tmp_path / "clip", False, "an output file", {".jpg"}) == "is a directory, not an output file"  # (a folder first: the suffix hid it)
    assert refusal(tmp_path / "x", False, "a video file", {".mp4"}, "video") == "unsupported video type '(none)'; use one of .mp4"
    atomic.refuse(tmp_path / "x.png", None, InputError)
    with pytest.raises(InputError, match=r"^/.*x\.png: no room$"):
        atomic.refuse(tmp_path / "x.png", "no room", InputError)

    cases = [
        (lambda p: check_output(p, False), GigapointError, "old.png", "already exists; pass overwrite=True to replace it"),
        (lambda p: check_output(p, False), GigapointError, "dir.mp4", "is a directory, not an output file"),
        (lambda p: check_output(p, False), GigapointError, "afile/x.png", f"{tmp_path / 'afile'} is a file, not a folder"),
        (lambda p: check_turntable(p, 2, 64, 48, 30.0), GigapointError, "dir.mp4", "is a directory, not a video file"),
        (lambda p: check_turntable(p, 2, 64, 48, 30.0), GigapointError, "clip", "is a directory, not a video file"),  # (a folder first, as an image's)
        (lambda p: check_turntable(p, 2, 64, 48, 30.0), GigapointError, "afile/x.mp4", f"{tmp_path / 'afile'} is a file, not a folder"),
        (lambda p: check_point_file_output(p, False), InputError, "dir.mp4", "is a directory, not a point file; not replaced"),
        (lambda p: check_point_file_output(p, False), InputError, "clip", "is a directory, not a point file; not replaced"),  # (was "not a  file")
        (lambda p: check_point_file_output(p, False), InputError, "dir.laz", "is a directory, not a LAZ file; not replaced"),
        (lambda p: check_point_file_output(p, False), InputError, "old.png", "already exists; pass overwrite=True to replace it"),
        (lambda p: check_point_file_output(p, True), InputError, "afile/x.laz", f"{tmp_path / 'afile'} is a file, not a folder"),
    ]
    for check, error, name, message in cases:
        with pytest.raises(error) as refused:
            check(tmp_path / name)
        assert str(refused.value) == f"{tmp_path / name}: {message}"
