"""The workers of the LocalCluster that ``--workers N`` starts (distributed.open_client): one
malloc arena, so that a task thread's freed memory is kept for the next task (keep_freed_memory.py),
Dask's profiler and fast event-loop ticks off (docs/scale.md), no Dask memory limit, and half the
RAM among them as the conversion's default limit (docs/lod.md); another cluster's workers size
that default by their own memory."""

from __future__ import annotations

import sys

import pytest

distributed = pytest.importorskip("distributed")
pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="glibc's malloc arenas and RUSAGE_THREAD are Linux's")


def _settings() -> tuple:
    import os

    import dask

    return os.environ.get("MALLOC_ARENA_MAX"), os.environ.get("NUMBA_NUM_THREADS"), dask.config.get("distributed.worker.profile.enabled")


def _faults_of_a_second_array(spec: dict) -> list[int]:
    """Page faults of making (and touching) two arrays of 48 and 40 MB, three times, on the task's thread."""
    import resource

    import numpy as np

    (np._core if hasattr(np, "_core") else np.core).multiarray._set_madvise_hugepage(False)  # 4 KiB pages: a fault a page, whatever the system's huge page setting
    faults = []
    for _ in range(3):
        before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        a, b = np.ones(6_000_000), np.ones(5_000_000)  # each fits a thread arena's 64 MiB heap, both do not
        faults.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)
        del a, b
    return faults


def test_own_workers_get_one_malloc_arena_and_no_profiler():
    from gigapoint.lod.convert.distributed import open_client

    with open_client(1) as client:
        assert set(client.run(_settings).values()) == {("1", "1", False)}


def test_a_task_thread_reuses_the_memory_its_last_array_freed():
    """Without the one-arena setting, a task thread's arrays live in thread-arena heaps, of which
    glibc unmaps every one but the first as soon as it empties: the second array faulted its
    ~10 000 pages in afresh every time."""
    from gigapoint.lod.convert.distributed import _task, open_client

    with open_client(1) as client:
        spec = {"own_workers": True, "out": ".", "tag": "probe"}
        faults = client.submit(_task, "read", "probe", spec, _faults_of_a_second_array, pure=False).result()
    if faults[0] < 15_000:  # transparent huge pages for every mapping ("always"): too few faults to tell
        pytest.skip(f"the first 88 MB of arrays faulted only {faults[0]} pages in")
    assert max(faults[1:]) < 1_000, faults


DRIVER_IMPORTING_GIGAPOINT_FIRST = '''
import gigapoint  # at the top: every spawned worker imports this script again, numba with it

def compile_in_the_worker(spec):
    from numba import njit

    @njit
    def one_more(x):
        return x + 1

    return one_more(41)

if __name__ == "__main__":
    from gigapoint.lod.convert.distributed import _task, open_client

    with open_client(1) as client:
        print("result", client.submit(_task, "read", "probe", {"out": ".", "tag": "probe"}, compile_in_the_worker, pure=False).result())
'''


def test_a_worker_of_a_script_that_imports_gigapoint_first_compiles(tmp_path):
    """A worker imports the driver script (and numba) before Dask sets its NUMBA_NUM_THREADS=1:
    its first compile re-read the environment and failed with "Cannot set NUMBA_NUM_THREADS to a
    different value once the threads have been launched" (a cold numba cache: every kernel)."""
    import subprocess

    script = tmp_path / "driver.py"
    script.write_text(DRIVER_IMPORTING_GIGAPOINT_FIRST)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "result 42" in done.stdout


_FILES_STOP_AT_1_MB = """
import resource, sys
resource.setrlimit(resource.RLIMIT_FSIZE, (1_000_000, 1_000_000))  # a file stops at 1 MB (workers inherit it): a full disk
from gigapoint.cli import main
sys.exit(main(["convert", sys.argv[1], "-o", sys.argv[2], "--workers", "2"]))
"""


def test_a_task_that_fails_on_our_own_workers_is_one_line(tmp_path):
    """A task failing on the workers ``--workers 2`` started (here: a raw chunk cut at 1 MB) is
    the conversion's one line naming the file; Dask's workers also logged it, seven lines of
    "Compute Failed", key, state, task, exception, traceback."""
    import subprocess
    from pathlib import Path

    autzen = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
    if not autzen.exists():
        pytest.skip("../shared/data/autzen_trim.laz is not here")
    out = tmp_path / "oct"
    proc = subprocess.run([sys.executable, "-c", _FILES_STOP_AT_1_MB, str(autzen), str(out)], capture_output=True, text=True, timeout=170)
    said = [line for line in proc.stderr.splitlines() if not line.startswith("while this runs")]
    assert proc.returncode == 1 and len(said) == 1, proc.stderr[-3000:]
    assert said[0].startswith(f"error: {out}/.partial/") and "bytes written (is the disk full?) (on Dask worker " in said[0], said
    # what became of the output, as one process says it (it was left out)
    assert said[0].endswith(f"; the conversion to {out} stopped unfinished (run it again once the cause is gone: it resumes)"), said


_OPEN_FILES_LIMITED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_NOFILE, (96, 96))  # workers inherit it (a login's is 1 024)
from gigapoint.cli import main
sys.exit(main(["convert", sys.argv[1], "-o", sys.argv[2], "--workers", "2"]))
"""


def test_a_folder_of_many_tiles_converts_on_workers_within_the_open_files_limit(tmp_path):
    """``convert TILES/ --workers 2`` of 1 500 tiles of 2 000 points stopped with "Too many open
    files (on Dask worker ..., build task p1)": the one partition's build mapped every tile's
    spilled chunk at once (peak 1 017 files open in a worker, a process's limit 1 024). Here 200
    tiles under a limit of 96 (a worker holds ~45 files of its own)."""
    import subprocess

    laspy = pytest.importorskip("laspy")
    import numpy as np

    tiles = tmp_path / "tiles"
    tiles.mkdir()
    rng = np.random.default_rng(0)
    for i in range(200):
        las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
        las.header.scales, las.header.offsets = [0.01] * 3, [0.0] * 3
        las.x, las.y, las.z = (i % 20) * 10 + rng.random(20) * 10, (i // 20) * 10 + rng.random(20) * 10, rng.random(20)
        las.write(tiles / f"t{i:03d}.laz")
    out = tmp_path / "oct"
    proc = subprocess.run([sys.executable, "-c", _OPEN_FILES_LIMITED, str(tiles), str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"{out}: 4,000 points in " in proc.stdout, proc.stdout


def _hold_1_1_gb(spec: dict) -> int:
    """1.1 GB of arrays made, written and read on the task's thread: bytes summed."""
    import numpy as np

    a = np.ones(137_500_000)  # 1.1 GB
    a[::512] = 2.0
    return int(a.sum()) - len(a)


def test_local_workers_share_the_ram_and_dask_stops_no_task_within_the_conversions_limit(monkeypatch, las_writer, tmp_path):
    """On a machine of 3 GiB, ``--workers 3``: Dask's default limit for its workers (the RAM split
    3 ways, 1 GiB) killed a worker whose task held 1.1 GB (at 95 %; paused it at 80 %, for good:
    its freed memory is kept), while the conversion planned each worker's tasks by its own limit,
    a quarter of the RAM (768 MiB: 4 such workers held all the RAM). Now Dask sets no limit of its
    own, and 3 workers on this machine plan half the RAM among them: 512 MiB each."""
    import dask

    from gigapoint.core import chunked
    from gigapoint.lod import ConvertError, convert
    from gigapoint.lod.convert.distributed import DaskPhases, _task, default_memory_limit, open_client
    from gigapoint.lod.convert.options import parse_memory

    monkeypatch.setattr(chunked, "physical_memory", lambda: 3 << 30)
    monkeypatch.setattr(distributed.system, "MEMORY_LIMIT", 3 << 30)  # (read here, where the LocalCluster sizes its workers)
    assert default_memory_limit(1) == parse_memory(None) == 768 << 20  # one worker: one process's default (the same octree)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), open_client(3) as client:
        assert default_memory_limit(client) == default_memory_limit(3) == 512 << 20
        planned = []  # the limit a conversion on these workers plans by

        def stop_at_start(conv):
            planned.append(conv.mem)
            raise ConvertError("stopped here")

        monkeypatch.setattr(DaskPhases, "_cluster_ready", stop_at_start)
        with pytest.raises(ConvertError, match="stopped here"):
            convert([las_writer(tmp_path / "a.las", 1_000)], tmp_path / "oct", client=client)
        assert planned == [512 << 20]
        spec = {"own_workers": True, "out": ".", "tag": "probe"}
        worker = [next(iter(client.scheduler_info()["workers"]))]
        assert client.submit(_task, "build", "big", spec, _hold_1_1_gb, workers=worker, pure=False).result() == 137_500_000 // 512 + 1
        # the same worker takes its next task (a paused one never would: it keeps the 1.1 GB)
        assert client.submit(_task, "build", "next", spec, _hold_1_1_gb, workers=worker, pure=False).result() == 137_500_000 // 512 + 1


def test_another_clusters_default_limit_follows_its_workers_memory_not_the_drivers(monkeypatch, las_writer, tmp_path, capsys):
    """A Client of one's own (or ``--dask ADDRESS``) planned each task by the driver's RAM, a
    quarter of it, which says nothing of the workers': a 64 GiB driver planned 16 GiB tasks for
    workers of 300 MB. Now a task plans for the smallest worker's memory, shared as a local
    cluster's (half among the tasks at once, at most a quarter each): its Dask memory limit, or
    where it has none, its machine's memory shared by such workers' threads there."""
    from gigapoint.core import chunked
    from gigapoint.lod import ConvertError, convert
    from gigapoint.lod.convert.distributed import DaskPhases, default_memory_limit

    monkeypatch.setattr(chunked, "physical_memory", lambda: 64 << 30)  # the driver's
    planned = []

    def stop_at_start(conv):
        planned.append((conv.mem, conv.partition_points))
        raise ConvertError("stopped here")

    monkeypatch.setattr(DaskPhases, "_cluster_ready", stop_at_start)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, memory_limit="300MB", processes=False, dashboard_address=":0") as cluster,
        distributed.Client(cluster) as client,
    ):
        with pytest.raises(ConvertError, match="stopped here"):
            convert([las_writer(tmp_path / "a.las", 1_000)], tmp_path / "oct", client=client)
        assert planned == [(75_000_000, 75_000_000 // 4 // 220)]  # a quarter of 300 MB; partitions by a quarter of that (state.py)
        assert default_memory_limit(client, say=True) == 75_000_000
    said = capsys.readouterr().err
    assert said.startswith("Dask: each task planned for 71 MiB, from worker inproc://") and said.endswith(
        "'s 286 MiB (Dask memory limit) among 1 thread(s) (--memory-limit sets it)\n"
    ), said
    monkeypatch.setattr(distributed.system, "memory_limit", lambda: 8 << 30)  # the workers' machine (here, this one)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=2, memory_limit=None, processes=False, dashboard_address=":0") as cluster,
        distributed.Client(cluster) as client,
    ):
        assert default_memory_limit(client) == 1 << 30  # 8 GiB, half of it among 4 threads


def test_a_scheduler_address_is_connected_to_once_for_the_memory_plan_and_the_run(monkeypatch, las_writer, tmp_path):
    """``convert(client=ADDRESS)`` connected to the scheduler twice: once to ask the workers'
    memory (default_memory_limit), again for the run. Now one Client plans the memory and runs
    the tasks, and is closed at the end; ``gigapoint convert --dask ADDRESS`` the same."""
    from gigapoint.cli import main
    from gigapoint.lod import convert
    from gigapoint.lod.convert.distributed import DaskPhases

    las = las_writer(tmp_path / "a.las", 1_000)
    monkeypatch.setattr(distributed.system, "memory_limit", lambda: 8 << 30)  # the worker's machine (this one), without a Dask limit
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, memory_limit=None, processes=False, dashboard_address=":0") as cluster:

        def connections() -> int:
            return sum(event.get("action") == "add-client" for _, event in cluster.scheduler.get_events("all"))

        at_start = []  # each run's memory limit, the scheduler's connections so far, the run's Client
        cluster_ready = DaskPhases._cluster_ready

        def seen_at_start(conv):
            at_start.append((conv.mem, connections(), conv.client))
            return cluster_ready(conv)

        monkeypatch.setattr(DaskPhases, "_cluster_ready", seen_at_start)
        assert convert([las], tmp_path / "oct", client=cluster.scheduler_address).points == 1_000
        assert main(["convert", str(las), "-o", str(tmp_path / "cli"), "--dask", cluster.scheduler_address, "-q"]) == 0
        after_both = connections()
    assert [(mem, seen) for mem, seen, _ in at_start] == [(2 << 30, 1), (2 << 30, 2)]  # a quarter of the worker's 8 GiB
    assert after_both == 2
    assert [run_client.status for *_, run_client in at_start] == ["closed", "closed"]


_SEVEN_WORKERS = {f"tcp://10.0.0.{i}:1": {"memory_limit": (i + 1) * 2**30, "nthreads": 1, "host": f"10.0.0.{i}"} for i in range(7)}


class _ListsFive:
    """A client of a Dask release whose scheduler_info lists 5 workers unless told -1."""

    def scheduler_info(self, n_workers: int = 5) -> dict:
        listed = list(_SEVEN_WORKERS.items())
        return {"workers": dict(listed if n_workers == -1 else listed[:n_workers])}


class _ListsAll(_ListsFive):
    """A client of a release before the argument: every worker, always."""

    def scheduler_info(self) -> dict:
        return {"workers": dict(_SEVEN_WORKERS)}


@pytest.mark.parametrize("client", [_ListsFive(), _ListsAll()], ids=["lists-5-by-default", "no-argument"])
def test_every_worker_of_the_cluster_is_asked_whatever_dasks_release(client):
    """Some Dask releases list 5 workers by default: the memory plan (and the watchdog, and the
    write steps' choice) saw 5 of a cluster's workers."""
    from gigapoint.lod.convert.distributed import _workers

    assert sorted(_workers(client)) == sorted(_SEVEN_WORKERS)
