"""LAZ records decoded by a child process (io/laz_process.py, io/_laz_child.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import GigapointError, InputError
from gigapoint.io import laz_process
from gigapoint.io.las import LasReader

laspy = pytest.importorskip("laspy")


def _write_laz(path, n: int, point_format: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.2")
    header.scales = np.array([0.001] * 3)
    header.offsets = np.array([500_000.0, 4_000_000.0, 100.0])
    las = laspy.LasData(header)
    las.x = 500_000 + rng.uniform(0, 1000, n)
    las.y = 4_000_000 + rng.uniform(0, 800, n)
    las.z = 100 + rng.uniform(0, 50, n)
    las.intensity = rng.integers(0, 65535, n).astype(np.uint16)
    las.classification = rng.integers(0, 31, n).astype(np.uint8)
    las.gps_time = rng.uniform(0, 1e6, n)
    rgb = rng.integers(0, 65536, (n, 3)).astype(np.uint16)
    las.red, las.green, las.blue = rgb.T
    las.write(str(path))
    return path


def _corrupted(path, out):
    """``path`` with 20 kB of 0xFF two thirds into it: lazrs's GPS-time decoder recurses on it
    until the stack overflows (SIGSEGV in the process that decodes)."""
    data = bytearray(path.read_bytes())
    at = len(data) * 2 // 3
    data[at : at + 20_000] = b"\xff" * 20_000
    out.write_bytes(bytes(data))
    return out


def read_chunks(path, chunk_size, **kwargs):
    return LasReader().read_chunks(path, chunk_size, **kwargs)


@pytest.fixture
def children(monkeypatch):
    """The child processes (Popen) the reads of a test start, one a file (not the one small
    files share: laz_process.SHARED_MAX)."""
    monkeypatch.setattr(laz_process, "SHARED_MAX", 0)
    made = []
    init = laz_process.ChildRecords.__init__

    def recording(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self.child)

    monkeypatch.setattr(laz_process.ChildRecords, "__init__", recording)
    return made


def _same_chunks(a, b):
    assert [len(c) for c in a] == [len(c) for c in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.xyz, y.xyz)
        np.testing.assert_array_equal(x.rgba, y.rgba)
        assert x.scale == y.scale
        assert x.attributes.keys() == y.attributes.keys()
        for k in x.attributes:
            np.testing.assert_array_equal(x.attributes[k], y.attributes[k])
            assert x.attributes[k].dtype == y.attributes[k].dtype


@pytest.mark.parametrize("point_format", [3, 7])
@pytest.mark.parametrize(("chunk_size", "start", "stop"), [(7_000, 0, None), (1 << 20, 0, None), (6_000, 12_345, 40_001)])
def test_the_child_decodes_the_records_this_process_would(tmp_path, monkeypatch, children, point_format, chunk_size, start, stop):
    path = _write_laz(tmp_path / "a.laz", 50_003, point_format)
    child = list(read_chunks(path, chunk_size, start=start, stop=stop))
    assert len(children) == 1 and children[0].returncode is not None  # it decoded them, and it has ended
    monkeypatch.setenv(laz_process.ENV_SWITCH, "0")
    here = list(read_chunks(path, chunk_size, start=start, stop=stop))
    assert len(children) == 1  # no child this time
    _same_chunks(child, here)
    assert sum(len(c) for c in child) == (stop or 50_003) - start


@pytest.mark.parametrize("kernel", [True, False])
def test_numba_is_set_up_while_the_child_decodes_the_first_records(tmp_path, monkeypatch, kernel):
    """A file the decoding kernel reads (over NUMPY_MAX points) sets numba up (its first kernel
    call's ~0.45 s) before this process waits on the child for the first records, not after
    them while the child waits for this process; a small file (numpy's) not at all."""
    from gigapoint.io import las

    events = []
    monkeypatch.setattr(las, "prepare_kernel_calls", lambda: events.append("numba"))
    monkeypatch.setattr(laz_process, "SHARED_MAX", 0)  # the file's own child
    read = laz_process.ChildRecords.read

    def reading(self, n):
        events.append("read")
        return read(self, n)

    monkeypatch.setattr(laz_process.ChildRecords, "read", reading)
    monkeypatch.setattr(las, "NUMPY_MAX", 10_000 if kernel else 1 << 30)
    path = _write_laz(tmp_path / "a.laz", 30_000)
    chunks = list(read_chunks(path, 7_000))
    assert sum(len(c) for c in chunks) == 30_000
    assert events == (["numba"] if kernel else []) + ["read"] * 5  # a read a chunk


def test_a_crash_of_the_decoder_is_a_one_line_error_after_the_points_before_it(tmp_path, children):
    bad = _corrupted(_write_laz(tmp_path / "good.laz", 200_000), tmp_path / "bad.laz")
    got = 0
    with pytest.raises(InputError) as err:
        for chunk in read_chunks(bad, 10_000):
            got += len(chunk)
    message = str(err.value)
    assert message.startswith(f"{bad}: truncated or corrupt LAZ point data: reading failed after {got:,} of the 200,000 points")
    assert "\n" not in message
    assert got >= 50_000  # the LAZ chunks before the damage
    assert children and children[0].returncode is not None


def test_a_progressive_load_of_a_file_that_crashes_the_decoder_keeps_what_it_loaded(tmp_path):
    bad = _corrupted(_write_laz(tmp_path / "good.laz", 600_000), tmp_path / "bad.laz")
    cloud = gp.open(bad, progressive=True)  # decoded 250 k points at a time: the first chunk is whole
    with pytest.raises(GigapointError, match=r"bad\.laz: truncated or corrupt LAZ point data"):
        cloud.wait(60)
    assert cloud.n_points >= 250_000
    cam = gp.Camera.fit(cloud.bounds, view="top", width=64, height=48)
    frame = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu"))
    assert np.count_nonzero(frame.visibility != EMPTY_PIXEL) > 0.5 * 64 * 48  # what was loaded is drawn
    cloud.close()


def _chunk_table(path) -> tuple[int, list]:
    """(where the point data starts, [(points, bytes)] a chunk) of a LAZ file."""
    import lazrs

    with laspy.open(path) as reader:
        vlr = next(v for v in reader.header.vlrs if v.record_id == 22204).record_data_bytes()
        offset = reader.header.offset_to_point_data
    with open(path, "rb") as f:
        f.seek(offset)
        return offset, lazrs.read_chunk_table(f, lazrs.LazVlr(vlr))


def _with_a_bad_laz_chunk(path, out, chunk: int):
    """``path`` (a LAZ file) with 400 random bytes 100 kB into its LAZ chunk ``chunk``: lazrs
    fails on that chunk (it runs out of the chunk's bytes), not on the others."""
    offset, table = _chunk_table(path)
    at = offset + 8 + sum(size for _, size in table[:chunk]) + 100_000
    data = bytearray(path.read_bytes())
    data[at : at + 400] = np.random.default_rng(0).integers(0, 256, 400, dtype=np.uint8).tobytes()
    out.write_bytes(bytes(data))
    return out, sum(points for points, _ in table[:chunk])


@pytest.mark.parametrize("chunk_size", [20_000, 250_000, 2_000_000])
def test_a_bad_laz_chunk_loses_itself_not_the_points_read_with_it(tmp_path, autzen_path, chunk_size):
    """A LAZ chunk lazrs fails on was the end of the whole slot the child decodes (a progressive
    load's 250 000 points, a conversion's 2 M): autzen_trim's 110 000 points, all lost with its
    second chunk. The child decodes that slot again chunk by chunk: the points before the bad
    chunk come, exactly the file's, then the one-line error."""
    import laspy

    bad, before = _with_a_bad_laz_chunk(autzen_path, tmp_path / "bad.laz", 1)
    assert before == 50_000
    got = []
    with pytest.raises(InputError) as err:
        for chunk in read_chunks(bad, chunk_size):
            got.append(chunk.xyz)
    assert str(err.value).startswith(f"{bad}: truncated or corrupt LAZ point data: reading failed after 50,000 of the 110,000 points")
    file = laspy.read(autzen_path)
    np.testing.assert_array_equal(np.concatenate(got), np.c_[file.x, file.y, file.z][:50_000])
    cloud = gp.open(bad, progressive=True)
    with pytest.raises(GigapointError, match=r"bad\.laz: truncated or corrupt LAZ point data"):
        cloud.wait(60)
    assert cloud.n_points == 50_000
    cloud.close()


def test_the_cli_says_a_decoder_crash_in_one_line_and_writes_nothing(tmp_path):
    bad = _corrupted(_write_laz(tmp_path / "good.laz", 200_000), tmp_path / "bad.laz")
    out = tmp_path / "out.png"
    run = subprocess.run([sys.executable, "-m", "gigapoint.cli", "render", str(bad), "-o", str(out), "-W", "32", "-H", "32"],
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert run.returncode not in (0, -signal.SIGSEGV)
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bad.laz" in lines[0] and "corrupt LAZ point data" in lines[0], run.stderr
    assert not out.exists()


def test_closing_the_chunks_stops_the_child(tmp_path, children):
    path = _write_laz(tmp_path / "a.laz", 50_000)
    chunks = read_chunks(path, 1_000)
    next(chunks)
    assert children[0].poll() is None  # waiting for its slots to be read
    chunks.close()
    assert children[0].returncode is not None


def _gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie nobody reaps counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_child_ends_when_its_parent_dies(tmp_path):
    path = _write_laz(tmp_path / "a.laz", 50_000)
    code = (
        "import os, signal, sys\n"
        "from gigapoint.io import laz_process, read_chunks\n"
        "init = laz_process.ChildRecords.__init__\n"
        "def recording(self, *a, **k):\n"
        "    init(self, *a, **k)\n"
        "    print(self.child.pid, flush=True)\n"
        "laz_process.ChildRecords.__init__ = recording\n"
        "laz_process.SHARED_MAX = 0\n"
        "next(read_chunks(sys.argv[1], 1_000))\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == -signal.SIGKILL
    pid = int(run.stdout.split()[0])
    deadline = time.monotonic() + 20
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)


def test_without_memfd_the_records_are_decoded_here(tmp_path, monkeypatch, children):
    path = _write_laz(tmp_path / "a.laz", 20_000)
    monkeypatch.delattr(os, "memfd_create")
    assert sum(len(c) for c in read_chunks(path, 5_000)) == 20_000
    assert children == []


def _block_of(path):
    """(file bytes, offset of the point data, LASzip VLR data, record bytes) of a LAZ file."""
    import io

    blob = path.read_bytes()
    header = laspy.LasHeader.read_from(io.BytesIO(blob))
    vlr = header.vlrs[header.vlrs.index("LasZipVlr")].record_data
    return blob, header.offset_to_point_data, vlr, header.point_count * header.point_format.size


def test_blocks_decoded_by_the_shared_child_are_laspys_records_even_after_a_crash(tmp_path, monkeypatch):
    """``decode_block`` (COPC and EPT nodes): the records laspy reads, from several threads at
    once; a block that crashes the decoder is a RuntimeError and the next block is decoded by a
    new child."""
    import threading

    good = _write_laz(tmp_path / "good.laz", 200_000)
    bad = _corrupted(good, tmp_path / "bad.laz")
    blob, skip, vlr, size = _block_of(good)
    expected = np.frombuffer(laspy.read(good).points.array.tobytes(), np.uint8)
    np.testing.assert_array_equal(laz_process.decode_block(blob, vlr, size, skip=skip), expected)
    with pytest.raises(RuntimeError, match="the LAZ decoder crashed with SIGSEGV"):
        laz_process.decode_block(_block_of(bad)[0], vlr, size, skip=skip)
    results = [None] * 4

    def decode(k):
        results[k] = laz_process.decode_block(blob, vlr, size, skip=skip)

    threads = [threading.Thread(target=decode, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        np.testing.assert_array_equal(r, expected)
    monkeypatch.setenv(laz_process.ENV_SWITCH, "0")  # decoded in this process: the same bytes
    np.testing.assert_array_equal(laz_process.decode_block(blob, vlr, size, skip=skip), expected)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")
def test_a_forked_process_starts_its_own_block_decoder(tmp_path):
    """After a fork both processes decode blocks, each through its own child (the parent's
    pipes are not the forked process's to use); run in a new process, which has no threads."""
    path = _write_laz(tmp_path / "a.laz", 30_000)
    code = (
        "import io, os, sys, laspy, numpy as np\n"
        "from gigapoint.io import laz_process\n"
        "blob = open(sys.argv[1], 'rb').read()\n"
        "h = laspy.LasHeader.read_from(io.BytesIO(blob))\n"
        "vlr = h.vlrs[h.vlrs.index('LasZipVlr')].record_data\n"
        "size = h.point_count * h.point_format.size\n"
        "expected = np.frombuffer(laspy.read(sys.argv[1]).points.array.tobytes(), np.uint8)\n"
        "def ok():\n"
        "    return np.array_equal(laz_process.decode_block(blob, vlr, size, skip=h.offset_to_point_data), expected)\n"
        "assert ok()\n"
        "parents = laz_process._blocks.child.pid\n"
        "pid = os.fork()\n"
        "if pid == 0:\n"
        "    good = ok() and laz_process._blocks.child.pid != parents\n"
        "    os._exit(0 if good else 3)\n"
        "_, status = os.waitpid(pid, 0)\n"
        "assert os.waitstatus_to_exitcode(status) == 0, status\n"
        "assert ok() and laz_process._blocks.child.pid == parents\n"
        "print('fine')\n"
    )
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "fine", run.stderr


def test_a_chunk_table_that_makes_lazrs_panic_is_a_one_line_error(tmp_path):
    """0xFF over a LAZ's chunk table: lazrs panics while it reads the table (in this process,
    before any decoding), and pyo3's PanicException is a BaseException that ``except Exception``
    misses. It is the file's one-line error everywhere, and Rust's own panic message is not
    printed around it."""
    import struct

    from gigapoint.io import file_info
    from gigapoint.io.las import read_las_header

    good = _write_laz(tmp_path / "good.laz", 600_000)  # (12 chunks: a smaller table decodes to absurd sizes, said too)
    data = bytearray(good.read_bytes())
    (table,) = struct.unpack_from("<q", data, read_las_header(good).offset_to_point_data)
    data[table + 8 :] = b"\xff" * (len(data) - table - 8)  # after the table's version and chunk count
    bad = tmp_path / "bad.laz"
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"bad\.laz: corrupt LAZ chunk table: index out of bounds"):
        next(read_chunks(bad, 10_000))
    with pytest.raises(InputError, match="corrupt LAZ chunk table"):
        file_info(bad)
    run = subprocess.run([sys.executable, "-m", "gigapoint.cli", "info", str(bad)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "RUST_BACKTRACE": "1"})  # fmt: skip
    assert run.returncode == 1
    assert run.stderr.strip().splitlines() == [f"error: {bad}: corrupt LAZ chunk table: index out of bounds: the len is 18 but the index is 20"]


def test_where_no_child_can_be_started_the_records_are_decoded_here(tmp_path, monkeypatch):
    path = _write_laz(tmp_path / "a.laz", 30_000)
    monkeypatch.setenv(laz_process.ENV_SWITCH, "0")
    here = list(read_chunks(path, 4_000, start=5_000))
    monkeypatch.delenv(laz_process.ENV_SWITCH)

    def no_process(*args, **kwargs):
        raise OSError("Resource temporarily unavailable")  # as fork() says at the process limit

    monkeypatch.setattr(laz_process.subprocess, "Popen", no_process)
    _same_chunks(list(read_chunks(path, 4_000, start=5_000)), here)
    blob, skip, vlr, size = _block_of(path)  # COPC's and EPT's blocks too
    monkeypatch.setattr(laz_process, "_blocks", None)
    expected = np.frombuffer(laspy.read(path).points.array.tobytes(), np.uint8)
    np.testing.assert_array_equal(laz_process.decode_block(blob, vlr, size, skip=skip), expected)


def _chunks_before(path, cut: int) -> int:
    """Points of the LAZ chunks of ``path`` whose bytes all lie before byte ``cut``."""
    offset, table = _chunk_table(path)
    end, points = offset + 8, 0
    for n, size in table:
        end += size
        if end > cut:
            break
        points += n
    return points


@pytest.mark.parametrize("point_format", [3, 7])
@pytest.mark.parametrize("share", [0.45, 0.7, 0.97])
def test_a_laz_file_cut_off_gives_the_points_before_the_cut(tmp_path, point_format, share):
    """A LAZ file cut off (a download or a copy that stopped) lost its chunk table with its tail:
    lazrs reads the table before any point, so nothing of it could be read. A progressive load
    (``read_salvaged``) decodes the chunks before the cut, exactly the file's points, at most a
    few thousand short of every chunk that lies before it, then says where the file ends; the
    plain reader still refuses the file up front."""
    full = _write_laz(tmp_path / "full.laz", 150_000, point_format)
    data = full.read_bytes()
    cut = int(len(data) * share)
    bad = tmp_path / "cut.laz"
    bad.write_bytes(data[:cut])
    with laspy.open(full) as reader:
        table = int.from_bytes(data[reader.header.offset_to_point_data :][:8], "little")
    with pytest.raises(InputError, match=r"cut\.laz: truncated or corrupt LAZ file: chunk table offset .* lies past the end of the file .*; `gigapoint view` shows the points before the cut"):
        list(LasReader().read_chunks(bad))
    expected = np.c_[laspy.read(full).x, laspy.read(full).y, laspy.read(full).z]
    for chunk_size in (20_000, 250_000):
        got = []
        with pytest.raises(InputError) as err:
            for chunk in LasReader().read_salvaged(bad, chunk_size):
                got.append(chunk.xyz)
        n = sum(len(x) for x in got)
        assert str(err.value) == f"{bad}: truncated or corrupt LAZ file: chunk table offset {table:,} lies past the end of the file ({cut:,} bytes): {n:,} of its 150,000 points read"
        assert _chunks_before(full, cut) - 5_000 <= n < 150_000
        assert n > 0
        np.testing.assert_array_equal(np.concatenate(got), expected[:n])
    cloud = gp.open(bad, progressive=True)
    with pytest.raises(GigapointError, match=r"cut\.laz: truncated or corrupt LAZ file"):
        cloud.wait(60)
    assert cloud.n_points == n and cloud.progress == pytest.approx(n / 150_000)
    cloud.close()


def test_a_laz_whose_chunk_table_offset_is_damaged_loads_whole_progressively(tmp_path):
    """The same way in for a LAZ whose data is whole but whose chunk table offset points past
    the end (a damaged header field): every point, exactly the file's, and no error."""
    full = _write_laz(tmp_path / "full.laz", 120_000, 7)
    data = bytearray(full.read_bytes())
    with laspy.open(full) as reader:
        start = reader.header.offset_to_point_data
    data[start : start + 8] = (10**15).to_bytes(8, "little")
    bad = tmp_path / "bad.laz"
    bad.write_bytes(bytes(data))
    got = np.concatenate([c.xyz for c in LasReader().read_salvaged(bad, 50_000)])
    las = laspy.read(full)
    np.testing.assert_array_equal(got, np.c_[las.x, las.y, las.z])


def test_a_laz_claiming_more_points_than_it_holds_does_not_say_it_failed_after_0(tmp_path):
    """A small LAZ is decoded whole by a child, which fails on the points its header claims
    beyond those it holds: nothing was given, and the error said "reading failed after 0 of the
    6,000 points", as if its first point were bad. Where the decoder got to is not known."""
    path = _write_laz(tmp_path / "a.laz", 5_000)
    data = bytearray(path.read_bytes())
    data[107:111] = (6_000).to_bytes(4, "little")  # LAS 1.2's point count
    path.write_bytes(bytes(data))
    with pytest.raises(InputError) as err:
        gp.open(path)
    assert str(err.value).startswith(f"{path}: truncated or corrupt LAZ point data: reading failed; the header claims 6,000 points (")
    assert "after" not in str(err.value)
