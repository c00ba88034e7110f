"""The conversion on Dask (lod/convert/distributed.py): a LocalCluster of 2 single-threaded worker
processes, shared by the module, converts a multi-file input into the single-process converter's
octree, file for file and byte for byte; workers killed mid-task, a driver killed mid-run, bad
inputs, an unreachable scheduler and an output a worker cannot write."""

from __future__ import annotations

import filecmp
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gigapoint.cli import main
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import ConvertError, OctreeDir, convert

distributed = pytest.importorskip("distributed")
laspy = pytest.importorskip("laspy")

pytestmark = pytest.mark.timeout(180)

# 260 000 town points in 3 files + a dense 30 000-point spot: ~16 partitions of <= 25 000 points
# (the spot is denser than the count grid shows, so one is refined), whose roots are joined in groups
OPTS = {"max_leaf": 3_000, "partition_points": 25_000, "chunk_size": 40_000}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, las_writer, points_las_writer) -> list[Path]:
    d = tmp_path_factory.mktemp("dask_in")
    files = [las_writer(d / f"town{i}.las", n, seed=i) for i, n in enumerate([120_000, 50_000, 90_000])]
    rng = np.random.default_rng(5)
    lo = np.array([float(v) for v in laspy.read(str(files[0])).header.mins])
    spot = lo + 20.0 + rng.random((30_000, 3)) * 0.05  # 30 000 points in a 5 cm cube: one count-grid cell
    files.insert(1, points_las_writer(d / "spot.las", spot, rng.integers(0, 65535, (30_000, 3)).astype(np.uint16)))
    return files


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", env={"NUMBA_NUM_THREADS": "1"}, silence_logs=40
    )
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture
def own_cluster():
    """``own_cluster(**options)``: a Client of a fresh LocalCluster (one single-threaded worker
    process unless ``options`` say otherwise), closed after the test: for a test that kills,
    spoils or rescales its workers, which the module's ``client`` must not see."""
    started = []

    def start(**options):
        cluster = distributed.LocalCluster(**{"n_workers": 1, "threads_per_worker": 1, "processes": True, "dashboard_address": ":0", "silence_logs": 50, **options})
        started.append((cluster, distributed.Client(cluster)))
        return started[-1][1]

    yield start
    for cluster, c in started:
        c.close()
        cluster.close()


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dask_ref") / "oct"
    convert(inputs, out, **OPTS)
    return out


def _files(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file())


def _assert_identical(a: Path, b: Path) -> None:
    """Every file of the two folders, byte for byte."""
    assert _files(a) == _files(b)
    differ = [f for f in _files(a) if not filecmp.cmp(a / f, b / f, shallow=False)]
    assert not differ, f"files differ: {differ}"


def _tasks(stream) -> dict[str, int]:
    kinds: dict[str, int] = {}
    for t in stream.data:
        kind = str(t["key"]).split("-")[3]
        kinds[kind] = kinds.get(kind, 0) + 1
    return kinds


def test_dask_output_is_the_single_process_output(inputs, reference, client, tmp_path):
    out = tmp_path / "oct"
    with distributed.get_task_stream(client) as stream:
        res = convert(inputs, out, client=client, **OPTS)
    assert res.points == 290_000 and not res.resumed
    _assert_identical(reference, out)
    kinds = _tasks(stream)
    # 8 read tasks (40 000-point ranges of the 3 town files and the spot), the spot's partition refined,
    # more than one build per worker, groups of partition roots
    assert kinds["read"] == 3 + 1 + 2 + 3 and kinds["refine"] == 1 and kinds["build"] >= 10 and kinds["group"] >= 1, kinds
    assert kinds["count"] == kinds["distribute"] == kinds["read"] and kinds["upper"] == 1 and kinds["place"] >= 1
    assert not OctreeDir(out).partial.exists()


def test_dask_words_layout_is_the_single_process_output(inputs, client, tmp_path):
    """The words layout (no compact streams) built by workers into their sets' own files and
    placed: the single process's bytes (a worker's set once touched the shared output arrays)."""
    convert(inputs, tmp_path / "one", layout="words", **OPTS)
    convert(inputs, tmp_path / "dask", client=client, layout="words", **OPTS)
    _assert_identical(tmp_path / "one", tmp_path / "dask")


@pytest.mark.parametrize("fmt", ["potree", "copc"])
def test_dask_potree_and_copc_outputs_are_the_single_process_outputs(inputs, client, tmp_path, fmt):
    name = "oct.copc.laz" if fmt == "copc" else "oct"
    (tmp_path / "ref").mkdir()
    (tmp_path / "dask").mkdir()
    convert(inputs[:2], tmp_path / "ref" / name, format=fmt, **OPTS)
    convert(inputs[:2], tmp_path / "dask" / name, format=fmt, client=client, **OPTS)
    _assert_identical(tmp_path / "ref", tmp_path / "dask")


def _install(dask_client, hook: str, kind: str, marker: Path) -> None:
    """On every worker: ``hooks.<hook>`` SIGKILLs its own process the first time a task of ``kind``
    gets there (the marker file, made with O_EXCL, says one already did: the retry goes on)."""

    def install(hook=hook, kind=kind, marker=str(marker)):
        from gigapoint.lod.convert import hooks

        def kill(k, name):
            if k == kind:
                try:
                    os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                except FileExistsError:
                    return
                os.kill(os.getpid(), signal.SIGKILL)

        setattr(hooks, hook, kill)

    dask_client.run(install)


def _uninstall(dask_client) -> None:
    def uninstall():
        from gigapoint.lod.convert import hooks

        hooks.task_started = lambda kind, name: None
        hooks.task_done = lambda kind, name: None

    dask_client.run(uninstall)


@pytest.mark.parametrize(
    ("hook", "kind"),
    [
        ("task_started", "build"),  # killed before it wrote anything
        ("task_done", "distribute"),  # killed after writing its pieces and removing its raw chunks
    ],
)
def test_a_worker_killed_mid_task_is_retried_and_the_output_is_the_same(inputs, reference, client, tmp_path, hook, kind):
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the hook travels to the workers by value
    marker = tmp_path / "killed"
    _install(client, hook, kind, marker)
    try:
        out = tmp_path / "oct"
        convert(inputs, out, client=client, **OPTS)
    finally:
        _uninstall(client)
        client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed one
    assert marker.exists()  # a worker was killed
    _assert_identical(reference, out)


def test_a_task_whose_worker_always_dies_fails_the_run_with_one_line(inputs, own_cluster, tmp_path):
    """allowed-failures = 0: the first worker death of a task is its last (KilledWorker)."""
    import cloudpickle
    import dask

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        c = own_cluster()
    _install(c, "task_started", "count", tmp_path / "killed")
    with pytest.raises(ConvertError, match=r"oct: the count task t\d+ failed because its worker died every time it ran") as err:
        convert(inputs[2:], tmp_path / "oct", client=c, **OPTS)
    assert "\n" not in str(err.value) and (tmp_path / "killed").exists()
    assert not OctreeDir(tmp_path / "oct").complete and OctreeDir(tmp_path / "oct").read_state()["phase"] == "count"


def test_a_killed_run_resumes_its_finished_partitions(inputs, reference, client, tmp_path):
    """The driver is SIGKILLed after 3 partitions are built; the same conversion resumes them."""
    out = tmp_path / "oct"
    code = (
        "import os, signal, sys, json; from gigapoint.lod.convert import hooks, convert\n"
        "hooks.after_partition_built = lambda done: done == 3 and os.kill(os.getpid(), signal.SIGKILL)\n"
        "a = json.loads(sys.argv[1]); convert(a['inputs'], a['out'], client=a['address'], **a['opts'])\n"
    )
    args = {"inputs": [str(p) for p in inputs], "out": str(out), "address": client.scheduler.address, "opts": OPTS}
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(args)], capture_output=True, timeout=150)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    state = OctreeDir(out).read_state()
    assert state["phase"] == "build" and not OctreeDir(out).complete
    import gigapoint as gp
    from gigapoint.errors import GigapointWarning

    with pytest.warns(GigapointWarning, match="conversion not finished"):  # the read tasks' samples, as the preview
        preview = gp.open(out)
    assert 0 < preview.n_points == state["preview"]["points"] and preview.bounds[0][2] >= state["lo"][2]
    built = [p.name for p in OctreeDir(out).built.iterdir() if p.name.startswith("p") and not p.name.endswith(".tmp")]
    assert len(built) >= 3
    n_parts = sum(1 for n in state["part_counts"] if n)
    with distributed.get_task_stream(client) as stream:
        res = convert(inputs, out, client=client, **OPTS)
    assert res.resumed
    kinds = _tasks(stream)
    assert "read" not in kinds and "distribute" not in kinds and kinds["build"] <= n_parts - len(built), kinds
    _assert_identical(reference, out)


def test_a_run_interrupted_here_starts_over_on_dask_to_the_same_bytes(inputs, reference, client, tmp_path, stop_conversion_after, monkeypatch):
    """Sets built here wrote their bit streams in place (writer.append_streams), those the Dask
    workers build keep their own: a Dask run does not take up a single-process run's state
    (its layout differs), and nothing of it is left in the octree. The warning that it starts
    over names OUT as given, as one process does (it named the driver's absolute path)."""
    monkeypatch.chdir(tmp_path)
    out = Path("oct")
    stop_conversion_after(3)
    with pytest.raises(KeyboardInterrupt):
        convert(inputs, out, **OPTS)
    stop_conversion_after(None)
    assert list((out / ".partial").glob("*.stream.npy")), "the sets built here wrote their streams in place"
    with pytest.warns(GigapointWarning, match=r"^oct: the unfinished conversion there was started with other inputs or options: starting over$"):
        res = convert(inputs, out, client=client, **OPTS)
    assert not res.resumed
    _assert_identical(reference, out)


def test_dask_pieces_hold_constant_attributes_as_their_value_alone(inputs, reference, client, tmp_path, stop_conversion_after):
    """The read tasks note the attributes every point holds one value of (a LAS file's flags,
    its user_data: ~7 bytes a point); the distribute tasks' pieces leave them out and each
    build makes them again: the single-process output, byte for byte, after a resume too."""
    out = tmp_path / "oct"
    stop_conversion_after(1)
    with pytest.raises(KeyboardInterrupt):
        convert(inputs, out, client=client, **OPTS)
    stop_conversion_after(None)
    state = OctreeDir(out).read_state()
    constant = {a for a, c in state["constant"].items() if c is not None}
    assert {"synthetic", "withheld", "user_data"} <= constant and not {"intensity", "classification"} & constant
    arrays = {p.name.split(".", 1)[1] for p in OctreeDir(out).parts.glob("t*") if p.suffix != ".json"}
    assert arrays == {"xyz", "rgba", *("attr." + a for a in state["attributes"] if a not in constant)}
    convert(inputs, out, client=client, **OPTS)
    _assert_identical(reference, out)


def test_cli_dask_option_gives_the_single_process_output(inputs, client, tmp_path, capsys):
    """Defaults (one partition: the build reads the spilled chunks) through `gigapoint convert --dask`."""
    ref, out = tmp_path / "ref", tmp_path / "oct"
    convert(inputs[2:], ref, max_leaf=3_000)
    assert main(["convert", *map(str, inputs[2:]), "-o", str(out), "--max-leaf", "3000", "--dask", client.scheduler.address]) == 0
    printed = capsys.readouterr()
    assert "140,000 points" in printed.out
    assert f"Dask dashboard: {client.dashboard_link}" in printed.err  # the scheduler serves one
    _assert_identical(ref, out)


def test_cli_workers_option_starts_a_local_cluster(inputs, tmp_path, capsys):
    ref, out = tmp_path / "ref", tmp_path / "oct"
    convert(inputs[1:2], ref, max_leaf=3_000)
    assert main(["convert", str(inputs[1]), "-o", str(out), "--max-leaf", "3000", "--workers", "1", "-q"]) == 0
    assert "30,000 points" in capsys.readouterr().out
    _assert_identical(ref, out)
    assert main(["convert", str(inputs[1]), "-o", str(tmp_path / "x"), "--workers", "1", "--dask", "tcp://127.0.0.1:9"]) == 1
    assert "give one of them" in capsys.readouterr().err
    many = 4 * (os.cpu_count() or 1) + 1  # (1000 started 1000 processes on 2 cores: the run never came back)
    assert main(["convert", str(inputs[1]), "-o", str(tmp_path / "y"), "--workers", str(many)]) == 1
    err = capsys.readouterr().err
    assert f"--workers: {many} local worker processes on a machine of {os.cpu_count()} cores" in err and "--dask" in err
    assert not (tmp_path / "y").exists()


def test_a_memory_limit_gives_one_process_and_workers_the_same_partitions_and_bytes(tmp_path, points_las_writer):
    """`--memory-limit 300M` plans partitions of <= 514 747 points (the limit less a fixed
    allowance for the runtime) in one process as with `--workers 2`. The plan came from each
    process's own size: 622 000 points a partition in one process, 507 000 in a `--workers`
    driver (Dask loaded), so the octant holding 575 000 of these 1.1 M points was one partition
    in one process and 8 on Dask, and 9 of the octree's files differed. Both run as `gigapoint
    convert` in processes of their own, as a user runs them."""
    rng = np.random.default_rng(3)
    xyz = rng.random((1_100_000, 3)) * 100
    xyz[:500_000] /= 2  # 500 000 more points in the first octant
    src = points_las_writer(tmp_path / "in.las", xyz, rng.integers(0, 65535, (len(xyz), 3)).astype(np.uint16))
    code = (  # `gigapoint ARGS`, saying how many partitions it built
        "import sys; from gigapoint.cli import main; from gigapoint.lod.convert import hooks\n"
        "built = []; hooks.after_partition_built = built.append\n"
        "rc = main(sys.argv[1:]); print('partitions', max(built)); sys.exit(rc)\n"
    )
    parts = {}
    for name, more in (("one", []), ("dask", ["--workers", "2"])):
        args = ["convert", str(src), "-o", str(tmp_path / name), "--memory-limit", "300M", "-q", *more]
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=150)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert "1,100,000 points" in proc.stdout
        parts[name] = proc.stdout.split()[-1]
    _assert_identical(tmp_path / "one", tmp_path / "dask")
    assert parts == {"one": "15", "dask": "15"}  # the dense octant in 8


def test_16bit_colors_dark_after_bright_read_in_parts_are_the_single_process_colors(client, tmp_path, points_las_writer):
    """io's color decision never goes back from 16-bit: a dark part of a 16-bit file read by its
    own task decides 8-bit, is found out once the parts before it are read, and is read again."""
    rng = np.random.default_rng(3)
    xyz = rng.random((100_000, 3)) * 100
    rgb = rng.integers(0, 65535, (100_000, 3)).astype(np.uint16)
    rgb[40_000:] = rng.integers(1, 255, (60_000, 3))  # the 2nd and 3rd 40 000-point ranges: 8-bit values
    src = points_las_writer(tmp_path / "mixed.las", xyz, rgb)
    ref, out = tmp_path / "ref", tmp_path / "oct"
    convert([src], ref, **OPTS)
    with distributed.get_task_stream(client) as stream:
        convert([src], out, client=client, **OPTS)
    assert _tasks(stream)["read"] == 3 + 2  # the two dark parts again
    _assert_identical(ref, out)


def test_a_damaged_laz_fails_the_run_naming_its_damaged_chunk_as_in_one_process(autzen_path, client, tmp_path):
    """lazrs decodes damaged bytes into points far outside the header's bounds without a word
    (test_io_las.damaged_autzen): a worker's read names the first of them and its LAZ chunk,
    and the run stops with the single-process converter's line, word for word (both add that it
    stopped: a Dask run now counts the points read before the damaged file and keeps OUT)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
    from test_io_las import DAMAGE, damaged_autzen

    path = damaged_autzen(autzen_path, tmp_path)
    errors = []
    for run, dask in (("one", None), ("dask", client)):
        with pytest.raises(InputError) as err:
            convert(path, tmp_path / run, client=dask, **OPTS)
        errors.append(str(err.value).replace(str(tmp_path / run), "OUT"))
    assert errors[0].startswith(f"{path}: {DAMAGE}; the conversion to OUT stopped unfinished") and errors[1] == errors[0]


@pytest.mark.parametrize("kind", ["truncated LAS", "bad text line"])
def test_a_corrupt_file_among_many_fails_the_run_naming_it(inputs, client, tmp_path, kind):
    """A truncated LAS is found by the driver's look at the headers; a text file with a bad line
    3 000 lines in fails in a worker's read task."""
    if kind == "truncated LAS":
        bad = tmp_path / "bad.las"
        data = inputs[0].read_bytes()
        bad.write_bytes(data[: len(data) // 2])  # the header claims twice the points there are
        message = r"bad\.las: truncated"
    else:
        bad = tmp_path / "bad.xyz"
        lines = [f"{x:.3f} {y:.3f} {z:.3f}" for x, y, z in laspy.read(str(inputs[2])).xyz[:5000]]
        lines[3000] = "1.0 oops 3.0"
        bad.write_text("\n".join(lines) + "\n")
        message = r"bad\.xyz: line 3001: 'oops' is not a number"
    out = tmp_path / "oct"
    t = time.perf_counter()
    with pytest.raises(InputError, match=message) as err:
        convert([*inputs[:2], bad], out, client=client, **OPTS)
    assert "\n" not in str(err.value) and time.perf_counter() - t < 60
    assert not OctreeDir(out).complete and not (out / "octree.json").exists()


def test_an_unreachable_scheduler_is_a_one_line_error(inputs, tmp_path, capsys, monkeypatch):
    from gigapoint.lod.convert import distributed as gd

    monkeypatch.setattr(gd, "CONNECT_TIMEOUT_S", 2.0)
    t = time.perf_counter()
    code = main(["convert", str(inputs[0]), "-o", str(tmp_path / "oct"), "--dask", "tcp://127.0.0.1:9", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and time.perf_counter() - t < 30
    assert err.startswith("error: --dask tcp://127.0.0.1:9: cannot reach a Dask scheduler") and err.count("\n") == 1, err
    assert not (tmp_path / "oct").exists()


def test_a_port_where_nothing_listens_is_said_at_once(inputs, tmp_path, capsys):
    """Dask retries a refused connection until its 10 s timeout (a typo in the port waited it out)."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # free once closed
    t = time.perf_counter()
    code = main(["convert", str(inputs[0]), "-o", str(tmp_path / "oct"), "--dask", f"tcp://127.0.0.1:{port}", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and time.perf_counter() - t < 5
    assert err == f"error: --dask tcp://127.0.0.1:{port}: cannot reach a Dask scheduler there (nothing listens on that port)\n", err


def test_a_port_where_no_scheduler_answers_is_a_one_line_error_in_time(inputs, tmp_path, capsys, monkeypatch):
    """A server that takes the connection but never answers (the dashboard's HTTP port): Dask's
    Client waited for its handshake for good."""
    import socket

    from gigapoint.lod.convert import distributed as gd

    monkeypatch.setattr(gd, "CONNECT_TIMEOUT_S", 1.0)
    with socket.create_server(("127.0.0.1", 0)) as silent:  # the kernel accepts; nobody answers
        t = time.perf_counter()
        code = main(["convert", str(inputs[0]), "-o", str(tmp_path / "oct"), "--dask", f"tcp://127.0.0.1:{silent.getsockname()[1]}", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and time.perf_counter() - t < 10
    assert "does not answer as a Dask scheduler within 1 s (the dashboard's port?" in err and err.count("\n") == 1, err


def test_a_scheduler_without_workers_is_a_one_line_error(inputs, own_cluster, tmp_path, monkeypatch):
    from gigapoint.lod.convert import distributed as gd

    monkeypatch.setattr(gd, "WORKER_WAIT_S", 1.0)
    address = own_cluster(n_workers=0, silence_logs=40).cluster.scheduler_address
    t = time.perf_counter()
    with pytest.raises(ConvertError, match=r"tcp://\S+: no Dask worker joined the scheduler within 1 s"):
        convert(inputs[:1], tmp_path / "oct", client=address, **OPTS)
    assert time.perf_counter() - t < 30
    assert not OctreeDir(tmp_path / "oct").complete


def test_an_output_a_worker_cannot_write_is_a_one_line_error(inputs, client, tmp_path):
    """The workers run as root here, for whom permissions do not count: the workers' probe is made
    to meet a read-only folder (its temporary file creation fails with EACCES)."""

    def deny():
        import tempfile

        def mkstemp(*a, dir=None, **k):
            raise PermissionError(13, "Permission denied", dir)

        tempfile._real_mkstemp = tempfile.mkstemp
        tempfile.mkstemp = mkstemp

    def allow():
        import tempfile

        tempfile.mkstemp = tempfile._real_mkstemp

    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    out = tmp_path / "oct"
    client.run(deny)
    try:
        with pytest.raises(ConvertError, match=r"oct: Dask worker tcp://\S+ cannot write into it \(Permission denied\)") as err:
            convert(inputs[:1], out, client=client, **OPTS)
    finally:
        client.run(allow)
    assert "\n" not in str(err.value)
    assert not OctreeDir(out).complete and not OctreeDir(out).raw.exists()  # nothing was read


def test_no_dask_import_without_a_client_and_an_install_hint_without_dask(inputs, tmp_path, monkeypatch):
    code = "import sys, gigapoint.lod.convert, gigapoint.cli.convert_cmd; assert 'distributed' not in sys.modules and 'dask' not in sys.modules"
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 0
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ConvertError, match=r"pip install 'gigapoint\[dask\]'"):
        convert(inputs[:1], tmp_path / "oct", client=2)
    assert not (tmp_path / "oct").exists()


def test_chunk_inputs_cannot_go_to_workers(client, tmp_path):
    from gigapoint.io import demo_chunks

    with pytest.raises(ConvertError, match="reads files"):
        convert(demo_chunks(1000), tmp_path / "oct", client=client)
    assert not (tmp_path / "oct").exists()


def test_an_empty_las_tile_among_several_is_skipped_as_in_one_process(inputs, client, tmp_path, points_las_writer):
    """Its whole-file read task failed on a worker: 'LAS file holds no points', the run stopped."""
    from gigapoint.errors import GigapointWarning

    empty = points_las_writer(tmp_path / "empty.las", np.zeros((0, 3)), np.zeros((0, 3), np.uint16))
    with pytest.warns(GigapointWarning, match=f"{empty}: holds no points, skipped"):
        res = convert([inputs[1], empty], tmp_path / "oct", client=client, **OPTS)
    assert res.points == 30_000


def test_empty_npy_ply_and_text_files_among_several_are_skipped_as_in_one_process(client, tmp_path):
    """Only LAS/LAZ tiles were counted before their read task: an empty NPY, PLY or text file
    failed on a worker ('NPY array holds no points') and stopped the run; one process skips
    them with a warning."""
    from plyfile import PlyData, PlyElement

    from gigapoint.errors import GigapointWarning

    rng = np.random.default_rng(4)
    full = tmp_path / "full.npy"
    np.save(full, rng.random((20_000, 3)) * 50)
    np.save(tmp_path / "empty.npy", np.zeros((0, 3)))
    PlyData([PlyElement.describe(np.zeros(0, [("x", "f4"), ("y", "f4"), ("z", "f4")]), "vertex")]).write(str(tmp_path / "empty.ply"))
    (tmp_path / "empty.xyz").write_text("# x y z\n")
    empties = [tmp_path / n for n in ("empty.npy", "empty.ply", "empty.xyz")]
    counts = []
    for name, kw in (("one", {}), ("dask", {"client": client})):
        with pytest.warns(GigapointWarning) as said:
            res = convert([full, *empties], tmp_path / name, **OPTS, **kw)
        text = [str(w.message) for w in said]
        for e in empties:
            assert f"{e}: holds no points, skipped" in text, (name, text)
        counts.append(res.points)
    assert counts == [20_000, 20_000]


def test_las_point_formats_0_5_and_6_10_keep_one_scan_angle_as_in_one_process(client, tmp_path):
    """Files of point formats 3 and 7 (scan_angle_rank, degrees; scan_angle, 0.006 degrees): the
    read tasks on the workers read the former as scan_angle too (io/las.py's with_scan_angle),
    the single process's output byte for byte."""
    import gigapoint as gp

    rng = np.random.default_rng(3)
    for name, fmt in (("a.las", 3), ("b.las", 7)):
        las = laspy.LasData(laspy.LasHeader(point_format=fmt, version="1.4"))
        las.header.scales, las.header.offsets = [0.001] * 3, [0.0] * 3
        las.x, las.y, las.z = rng.uniform(0, 100, (3, 20_000))
        if fmt == 3:
            las.scan_angle_rank = rng.integers(-90, 91, 20_000).astype(np.int8)
        else:
            las.scan_angle = rng.integers(-15_000, 15_001, 20_000).astype(np.int16)
        las.write(str(tmp_path / name))
    paths = [tmp_path / "a.las", tmp_path / "b.las"]
    with pytest.warns(gp.GigapointWarning, match=r"attribute\(s\) overlap, scanner_channel not in every file"):
        convert(paths, tmp_path / "one", **OPTS)
    with pytest.warns(gp.GigapointWarning, match=r"attribute\(s\) overlap, scanner_channel not in every file"):
        convert(paths, tmp_path / "dask", client=client, **OPTS)  # (Dask said no word of them)
    _assert_identical(tmp_path / "one", tmp_path / "dask")
    assert "scan_angle" in gp.open(tmp_path / "dask").attribute_names


def test_a_rerun_waits_for_a_task_its_interrupted_driver_left_running(thread_client, tmp_path, las_writer, monkeypatch):
    """A driver's Ctrl+C (or death) releases its tasks: the scheduler forgets a running one at once,
    but the worker runs it to its end, writing into OUT. A re-run must not start beside it."""
    from gigapoint.lod.convert import distributed as gd
    from gigapoint.lod.convert import hooks

    src = las_writer(tmp_path / "a.las", 20_000)
    out = (tmp_path / "oct").resolve()
    started, ended = [], []
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: started.append(time.monotonic()))
    monkeypatch.setattr(hooks, "task_done", lambda kind, name: name == "p0" and ended.append(time.monotonic()))

    def left_running(spec):
        time.sleep(2.0)

    spec = {"tag": gd.output_tag(out), "out": str(out)}
    orphan = thread_client.submit(gd._task, "build", "p0", spec, left_running, pure=False)
    while not started:
        time.sleep(0.02)
    thread_client.cancel(orphan)  # as the interrupted driver's client does
    convert([src], out, client=thread_client, max_leaf=3_000)
    assert ended and len(started) > 1 and started[1] > ended[0], (started, ended)


def test_an_input_a_worker_does_not_see_is_named_as_such(thread_client, tmp_path, las_writer, monkeypatch):
    """On a cluster the workers are other machines: an input only the driver sees (gone here
    once its read task starts) is named with what to do, not as a bare "no such file"."""
    from gigapoint.lod.convert import hooks

    src = las_writer(tmp_path / "a.las", 20_000)
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: kind == "read" and src.unlink(missing_ok=True))
    with pytest.raises(ConvertError) as err:
        convert([src], tmp_path / "oct", client=thread_client)
    msg = str(err.value)
    assert msg.startswith(f"{src.resolve()}: Dask worker inproc://") and "does not see this input, which the driver does" in msg, msg
    assert "every worker shares); the conversion to" in msg and msg.endswith("it resumes)") and "\n" not in msg


def test_a_worker_running_other_gigapoint_code_is_a_one_line_error(inputs, client, tmp_path, monkeypatch):
    """Workers import their own gigapoint: another release or a stale checkout would write other
    bytes (or fail on a task it does not know). Here the driver's code is the odd one."""
    from gigapoint.lod import code

    monkeypatch.setattr(code, "_CODE_VERSION", "0.0.1+000000000000")
    with pytest.raises(ConvertError) as err:
        convert(inputs[:1], tmp_path / "oct", client=client, **OPTS)
    msg = str(err.value)
    assert msg.startswith(f"{(tmp_path / 'oct').resolve()}: Dask worker tcp://") and "\n" not in msg, msg
    assert ", the driver 0.0.1+000000000000 (version+digest of the source): install the same gigapoint on every worker" in msg, msg


def _other_code() -> None:
    """On a worker: gigapoint seen as another release (as a worker of another install is)."""
    from gigapoint.lod import code

    code._CODE_VERSION = "0.0.1+000000000000"


def _no_writing() -> None:
    """On a worker: every temporary file in OUT refused (the workers run as root here, for whom permissions do not count)."""
    import tempfile

    def mkstemp(*a, dir=None, **k):
        raise PermissionError(13, "Permission denied", dir)

    tempfile.mkstemp = mkstemp


def _no_gigapoint() -> None:
    """On a worker: gigapoint cannot be imported, as where it is not installed."""

    class NotInstalled:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] == "gigapoint":
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)

    for name in [m for m in sys.modules if m.partition(".")[0] == "gigapoint"]:
        del sys.modules[name]
    sys.meta_path.insert(0, NotInstalled())


def test_a_worker_without_gigapoint_is_named_in_one_line(las_writer, own_cluster, tmp_path):
    """A worker that cannot import gigapoint failed the driver's check with Dask's failure to
    unpickle the check ('failed the driver's check (ModuleNotFoundError("No module named ...'))."""
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the spoiler travels to the worker by value
    out = tmp_path / "oct"
    c = own_cluster()
    c.run(_no_gigapoint)
    (worker,) = c.scheduler_info()["workers"]
    with pytest.raises(ConvertError) as err:
        convert([las_writer(tmp_path / "a.las", 2_000)], out, client=c)
    assert re.fullmatch(
        rf"{re.escape(str(out))}: Dask worker {re.escape(worker)} cannot import gigapoint \(No module named 'gigapoint'\): "
        r"install gigapoint \S+ there \(the driver's version\+digest of the source\)",
        str(err.value),
    ), err.value


@pytest.mark.parametrize(
    ("spoil", "problem"),
    [
        (_other_code, r"runs gigapoint 0\.0\.1\+000000000000, the driver \S+ \(version\+digest of the source\): install the same gigapoint"),
        (_no_writing, r"cannot write into it \(Permission denied\)"),
    ],
    ids=["other code", "cannot write OUT"],
)
def test_a_worker_that_joins_after_the_check_is_checked_before_its_first_task(las_writer, own_cluster, tmp_path, monkeypatch, spoil, problem):
    """The driver checks the workers there when the run starts (code, OUT seen and writable); one
    that joins later (an autoscaling cluster) ran its tasks unchecked. Here worker A passes the
    check, then B joins, spoilt, and A leaves: B's first task says why it cannot run, in one line."""
    import cloudpickle

    from gigapoint.lod.convert.distributed import DaskPhases

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the spoilers travel to the worker by value
    src = las_writer(tmp_path / "a.las", 20_000)
    out = tmp_path / "oct"
    c = own_cluster(env={"NUMBA_NUM_THREADS": "1"}, silence_logs=40)
    checked = DaskPhases.output_ready
    late = []

    def output_ready_then_a_worker_joins(conv):
        checked(conv)
        (first,) = c.scheduler_info()["workers"]
        c.cluster.scale(2)
        c.wait_for_workers(2, timeout=60)
        late.extend(w for w in c.scheduler_info()["workers"] if w != first)
        c.run(spoil, workers=late)
        c.retire_workers([first], close_workers=True)

    monkeypatch.setattr(DaskPhases, "output_ready", output_ready_then_a_worker_joins)
    with pytest.raises(ConvertError) as err:
        convert([src], out, client=c, max_leaf=3_000)
    msg = str(err.value)
    assert re.fullmatch(f"{re.escape(str(out))}: Dask worker {re.escape(late[0])} {problem}.*", msg), msg
    assert "\n" not in msg
    raw = OctreeDir(out).raw
    assert not OctreeDir(out).complete and not (raw.exists() and any(raw.iterdir()))  # nothing was read


def test_ctrl_c_waits_for_the_tasks_running_on_the_workers(thread_client, tmp_path, las_writer, monkeypatch, stop_conversion_after, capsys):
    """Dask cannot stop a running task: after Ctrl+C the driver waits for its running tasks,
    so that nothing writes into OUT once it has returned (then a re-run resumes)."""
    from gigapoint.lod.convert import hooks

    src = las_writer(tmp_path / "a.las", 120_000)
    builds = {"started": 0, "done": 0}

    def started(kind, name):
        if kind == "build":
            builds["started"] += 1
            time.sleep(1.0)  # a build that takes a while

    monkeypatch.setattr(hooks, "task_started", started)
    monkeypatch.setattr(hooks, "task_done", lambda kind, name: kind == "build" and builds.__setitem__("done", builds["done"] + 1))
    stop_conversion_after(1)
    with pytest.raises(KeyboardInterrupt):
        convert([src], tmp_path / "oct", client=thread_client, **OPTS)
    assert builds["started"] >= 2 and builds["done"] == builds["started"], builds
    assert "Dask tasks still run into the output: waiting for them to end (Ctrl+C again leaves them" in capsys.readouterr().err
    stop_conversion_after(None)
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: None)
    assert convert([src], tmp_path / "oct", client=thread_client, **OPTS).resumed


def test_sigterm_to_the_cli_driver_waits_for_running_tasks_and_the_rerun_resumes(inputs, client, tmp_path):
    """SIGTERM (a batch system's stop) to `gigapoint convert --dask` once a partition is built:
    as after Ctrl+C, the driver waits for the builds running on the workers, exits 143 saying
    OUT is kept, and the same command resumes to the octree of an uninterrupted run."""
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    marks = tmp_path / "marks"
    marks.mkdir()

    def slow_builds(marks=str(marks)):
        from gigapoint.lod.convert import hooks

        def mark(state):
            def hook(kind, name):
                if kind == "build":
                    Path(marks, f"{state}-{name}").touch()
                    if state == "started":
                        time.sleep(2.0)  # a build still running when the driver gets SIGTERM

            return hook

        hooks.task_started, hooks.task_done = mark("started"), mark("done")

    out = tmp_path / "oct"
    opts = ["--memory-limit", "64M", "--max-leaf", "3000", "-q"]  # partitions of ~76 000 points: 4 or more
    code = (
        "import os, signal, sys; from gigapoint.cli import main; from gigapoint.lod.convert import hooks\n"
        "hooks.after_partition_built = lambda done: done == 1 and os.kill(os.getpid(), signal.SIGTERM)\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    args = ["convert", *map(str, inputs), "-o", str(out), "--dask", client.scheduler.address, *opts]
    client.run(slow_builds)
    try:
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)
    finally:
        _uninstall(client)
    started = {p.name.split("-", 1)[1] for p in marks.glob("started-*")}
    done = {p.name.split("-", 1)[1] for p in marks.glob("done-*")}
    assert proc.returncode == 143, proc.stderr[-2000:]
    assert len(started) >= 2 and done == started, (started, done)  # nothing ran on once the driver had gone
    lines = proc.stderr.splitlines()
    assert lines[0].endswith("Dask tasks still run into the output: waiting for them to end (Ctrl+C again leaves them; a re-run waits for them)")
    assert lines[1:] == [f"{out}: kept unfinished; run the same convert command again to resume it", "terminated"], lines
    res = convert(inputs, out, client=client, memory_limit="64M", max_leaf=3000)
    assert res.resumed
    convert(inputs, tmp_path / "ref", client=client, memory_limit="64M", max_leaf=3000)
    _assert_identical(tmp_path / "ref", out)


def test_a_bad_input_and_the_output_are_named_as_given_as_one_process_names_them(thread_client, tmp_path, las_writer, monkeypatch):
    """On Dask the error named the input and the output by their absolute paths (the workers'),
    where one process names them as the user gave them: now the same line either way."""
    from gigapoint.lod.convert import hooks

    las_writer(tmp_path / "a.las", 20_000)
    (tmp_path / "bad.xyz").write_text("1 2 3\n4 oops 6\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: name.startswith("bad") and time.sleep(1.0))  # read last, as one process does
    said = []
    for client in (None, thread_client):
        with pytest.raises(InputError) as err:
            convert([Path("a.las"), Path("bad.xyz")], Path("oct"), client=client, **OPTS)
        said.append(str(err.value))
        shutil.rmtree("oct", ignore_errors=True)
    assert said[0].startswith("bad.xyz: line 2: 'oops' is not a number; the conversion to oct stopped unfinished: "), said[0]
    assert said[1] == said[0]


def test_a_bad_input_read_after_others_keeps_out_as_one_process_does(thread_client, tmp_path, las_writer, monkeypatch):
    """A read task that fails on a bad file once other read tasks have finished: the driver
    counted no points until the read phase ended, so OUT was removed as if no input had given
    a point, and the error did not say what became of it. Now, as in one process, OUT stays
    (its state says why it stopped) and the line says so; a run without the file starts over."""
    from gigapoint.lod.convert import hooks

    good = [las_writer(tmp_path / f"{n}.las", 20_000, seed=i) for i, n in enumerate("ab")]
    lines = [f"{x:.3f} {y:.3f} {z:.3f}" for x, y, z in laspy.read(str(good[0])).xyz[:5000]]
    lines[3000] = "1.0 oops 3.0"
    bad = tmp_path / "bad.xyz"
    bad.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: name.startswith("bad") and time.sleep(1.0))  # read last
    out = tmp_path / "oct"
    with pytest.raises(InputError) as err:
        convert([*good, bad], out, client=thread_client, **OPTS)
    msg = str(err.value)
    assert msg == (
        f"{bad.resolve()}: line 3001: 'oops' is not a number; the conversion to {out.resolve()} stopped unfinished: "
        "run it again once that file is whole, or without it: it starts over"
    ), msg
    state = OctreeDir(out).read_state()
    assert state["points"] == 40_000 and state["stopped_by"].startswith(f"{bad.resolve()}: line 3001"), state
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: None)
    res = convert(good, out, client=thread_client, **OPTS)
    assert res.points == 40_000 and not res.resumed


def test_a_damaged_read_that_fails_before_the_reads_before_it_end_keeps_out_as_one_process_does(autzen_path, thread_client, tmp_path, monkeypatch):
    """The damaged LAZ's read of points 40 000.. failed while that of points 0.. still ran (a
    busy machine): the driver waited for it, but raised without taking in its points, so none
    were counted, OUT was removed and the line lacked what became of it (the flaky
    test_a_damaged_laz_fails_the_run_naming_its_damaged_chunk_as_in_one_process). Forced here:
    the first read ends only once the driver has seen a read fail."""
    import threading

    from gigapoint.lod.convert import distributed as gd
    from gigapoint.lod.convert import hooks

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
    from test_io_las import DAMAGE, damaged_autzen

    path = damaged_autzen(autzen_path, tmp_path)
    failure_seen = threading.Event()
    first_failed_read = gd._first_failed_read

    def seen(*args):
        failure_seen.set()
        return first_failed_read(*args)

    monkeypatch.setattr(gd, "_first_failed_read", seen)
    monkeypatch.setattr(hooks, "task_done", lambda kind, name: name == "damaged.laz:0" and failure_seen.wait(60))
    out = tmp_path / "oct"
    with pytest.raises(InputError) as err:
        convert(path, out, client=thread_client, **OPTS)
    assert failure_seen.is_set()
    assert str(err.value) == (
        f"{path}: {DAMAGE}; the conversion to {out} stopped unfinished: run it again once that file is whole, or without it: it starts over"
    )
    state = OctreeDir(out).read_state()
    assert state["points"] == 40_000 and state["stopped_by"] == f"{path}: {DAMAGE}", state


UTM = "EPSG:32610"
#: a quadrilateral over part of autzen, in its own CRS (feet): moved into the target before a point is read
SITE_FEET = [[636_200.0, 849_000.0], [637_000.0, 848_990.0], [636_900.0, 849_400.0], [636_300.0, 849_350.0], [636_200.0, 849_000.0]]


def test_to_crs_on_dask_is_the_single_process_octree(autzen_path, client, tmp_path):
    """The read tasks move each chunk as one process does (Reprojection.from_spec: the same CRSs
    and fast-path tolerance), the clip polygon moved into the target before the filter, the points
    spilled off the file's grid (float64): the same octree, byte for byte, in UTM metres."""
    pyproj = pytest.importorskip("pyproj")
    polygon = tmp_path / "site.geojson"
    polygon.write_text(json.dumps({"type": "Polygon", "coordinates": [SITE_FEET]}))  # (names no CRS: autzen's feet)
    results = {}
    for run, dask in (("one", None), ("dask", client)):
        with pytest.warns(GigapointWarning, match="z is kept as it is"):
            results[run] = convert(autzen_path, tmp_path / run, to_crs=UTM, clip_polygon=polygon, client=dask, **OPTS)
    assert 10_000 < results["dask"].points == results["one"].points < 100_000  # (a cut, not all or nothing)
    _assert_identical(tmp_path / "one", tmp_path / "dask")
    meta = json.loads((tmp_path / "dask" / "octree.json").read_text())
    assert pyproj.CRS.from_wkt(meta["crs"]) == pyproj.CRS.from_epsg(32610)
    lo, hi = meta["bounds"]["min"], meta["bounds"]["max"]
    assert 494_000 < lo[0] and hi[0] < 495_000 and 4_877_000 < lo[1] and hi[1] < 4_878_000  # (metres of UTM 10N, not autzen's feet)


def _colorize_helpers():
    """test_colorize.py's raster width, GeoTIFF writer, pattern and pixels under a file's points."""
    pytest.importorskip("rasterio")
    pytest.importorskip("pyproj")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_colorize import WIDTH, _geotiff, _pattern, _pixels_of

    return WIDTH, _geotiff, _pattern, _pixels_of


def test_colorize_on_dask_is_the_single_process_octree_and_counts_the_uncoloured(autzen_path, client, tmp_path):
    """Each read task opens the raster itself, blackens a colourless file's points, colours its
    chunks after the filter and counts those the raster leaves uncoloured: the same octree, byte
    for byte, and the same count, the points east of a raster over autzen's west half."""
    WIDTH, _geotiff, _pattern, _pixels_of = _colorize_helpers()
    no_rgb = tmp_path / "autzen_no_rgb.las"
    laspy.convert(laspy.read(str(autzen_path)), point_format_id=1).write(str(no_rgb))
    half = _geotiff(tmp_path / "west.tif", _pattern()[:, :, : WIDTH // 2], laspy.read(str(no_rgb)).header.parse_crs().to_wkt())
    east = int((_pixels_of(no_rgb)[1] >= WIDTH // 2).sum())
    assert 30_000 < east < 80_000
    results = {run: convert(no_rgb, tmp_path / run, colorize=half, client=dask, **OPTS) for run, dask in (("one", None), ("dask", client))}
    assert results["dask"].uncolored == results["one"].uncolored == east
    _assert_identical(tmp_path / "one", tmp_path / "dask")
    assert json.loads((tmp_path / "dask" / "octree.json").read_text())["has_color"] is True


def test_colorize_bits_on_dask_reach_the_workers(autzen_path, client, tmp_path):
    """The read tasks open the raster themselves and read its values as of the driver's bit depth
    (--colorize-bits 12 for a 16-bit raster of 0-4095 naming no NBITS; they took 16 bits: near black)."""
    _, _geotiff, _pattern, _ = _colorize_helpers()
    raster = _geotiff(tmp_path / "ortho12.tif", (_pattern().astype(np.uint16) << 4) | 15, laspy.read(str(autzen_path)).header.parse_crs().to_wkt())
    results = {run: convert(autzen_path, tmp_path / run, colorize=raster, colorize_bits=12, client=dask, **OPTS) for run, dask in (("one", None), ("dask", client))}
    assert results["dask"].uncolored == results["one"].uncolored == 0
    _assert_identical(tmp_path / "one", tmp_path / "dask")


def test_a_raster_a_worker_does_not_see_is_named_as_such(thread_client, tmp_path, las_writer, monkeypatch):
    """The read tasks open the --colorize raster themselves: one only the driver sees (gone here
    once a read task starts) is named with what to do, as an input is."""
    from gigapoint.lod.convert import hooks

    _, _geotiff, _pattern, _ = _colorize_helpers()
    src = las_writer(tmp_path / "a.las", 20_000)
    raster = _geotiff(tmp_path / "ortho.tif", _pattern(), None)
    monkeypatch.setattr(hooks, "task_started", lambda kind, name: kind == "read" and raster.unlink(missing_ok=True))
    with pytest.raises(ConvertError) as err, pytest.warns(GigapointWarning, match="names no CRS"):
        convert([src], tmp_path / "oct", colorize=raster, client=thread_client)
    msg = str(err.value)
    assert msg.startswith(f"{raster}: Dask worker inproc://") and "\n" not in msg, msg
    assert "does not see this raster (--colorize), which the driver does (it must be at the same path on a file system every worker shares)" in msg
    assert msg.endswith("it resumes)")
