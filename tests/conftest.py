"""Shared fixtures: small deterministic scenes and the shared sample data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
AUTZEN = SHARED_DATA / "autzen_trim.laz"


@pytest.fixture(scope="session")
def demo_small():
    """The demo scene at 200 000 points (20 batches)."""
    return gp.demo(200_000, scale=None)  # the three-word layout: exact-kernel tests and the reference image


@pytest.fixture(scope="session")
def autzen_path():
    if not AUTZEN.exists():
        pytest.skip(f"shared sample {AUTZEN} not present")
    return AUTZEN


@pytest.fixture(scope="session")
def autzen_layered(autzen_path, tmp_path_factory):
    """autzen_trim converted with leaves of at most 2,000 points (levels 0-4, spacing 9.2 ft at
    the root: 2.3 ft at level 2) to a gigapoint octree folder and a COPC file: {kind: path}."""
    out = tmp_path_factory.mktemp("layered")
    gp.convert([autzen_path], out / "autzen_octree", max_leaf=2_000)
    gp.convert([autzen_path], out / "autzen.copc.laz", format="copc", max_leaf=2_000)
    return {"gigapoint": out / "autzen_octree", "copc": out / "autzen.copc.laz"}


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def stop_conversion_after(monkeypatch):
    """``stop_conversion_after(n)``: conversions in this process raise KeyboardInterrupt once they
    have built ``n`` partitions in a run (lod/convert/hooks.py); ``None``: they run through."""
    from gigapoint.lod.convert import hooks

    def arm(n: int | None) -> None:
        def hook(done: int) -> None:
            if done == n:
                raise KeyboardInterrupt(f"test interrupt after {done} partitions")

        monkeypatch.setattr(hooks, "after_partition_built", hook)

    return arm


@pytest.fixture
def interrupted_read(monkeypatch):
    """``interrupted_read(run)``: ``run()``, a conversion, stopped by Ctrl+C once its read phase has
    taken two chunks (this test's conversions held out of core: resumable mid-read); the
    conversions after it read through."""
    import importlib

    read = importlib.import_module("gigapoint.lod.convert.read")
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)
    real = read._read_chunks

    def stops(path, size):
        chunks = real(path, size)
        yield next(chunks)
        yield next(chunks)
        raise KeyboardInterrupt("test")

    def interrupt(run) -> None:
        monkeypatch.setattr(read, "_read_chunks", stops)
        try:
            with pytest.raises(KeyboardInterrupt):
                run()
        finally:
            monkeypatch.setattr(read, "_read_chunks", real)

    return interrupt


def write_las(path: Path, xyz: np.ndarray, rgb16: np.ndarray, intensity=None, classification=None, scale: float = 0.001) -> Path:
    """The points ``xyz`` with their 16-bit colours ``rgb16`` as a LAS 1.2 file (point format 3,
    ``scale`` on each axis, millimetres by default, offsets 0); intensity each point's index
    (wrapping at 65 536) and classification 0 where not given."""
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [scale] * 3
    header.offsets = [0.0, 0.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.red, las.green, las.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    las.intensity = np.arange(len(xyz), dtype=np.uint16) if intensity is None else intensity
    if classification is not None:
        las.classification = classification
    las.write(str(path))
    return path


def write_demo_las(path: Path, n: int, seed: int = 0) -> Path:
    """The demo scene's first n points as ``write_las`` writes them, with their classes."""
    from gigapoint.io import demo_arrays

    xyz, rgba, attrs = demo_arrays(n, seed)
    return write_las(path, xyz, rgba[:, :3].astype(np.uint16) * 257, attrs["intensity"], attrs["classification"])


@pytest.fixture(scope="session")
def las_writer():
    """``write_demo_las(path, n, seed=0)`` for tests that need LAS input files."""
    pytest.importorskip("laspy")
    return write_demo_las


@pytest.fixture(scope="session")
def points_las_writer():
    """``write_las(path, xyz, rgb16, intensity=None, classification=None, scale=0.001)``: a LAS
    input file of the test's own points."""
    pytest.importorskip("laspy")
    return write_las


@pytest.fixture
def cli(capsys):
    """``cli(*args)``: ``gigapoint ARGS`` run in this process -> (exit status, stdout, stderr);
    each argument is passed as ``str(arg)``."""
    from gigapoint.cli import main

    def run(*args):
        rc = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return rc, out, err

    return run


@pytest.fixture(scope="module")
def thread_client():
    """A Dask Client of a LocalCluster of one two-thread worker in this process, a module's, for
    conversions on Dask that need no worker processes (a test that kills, spoils or rescales its
    workers starts a cluster of its own)."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0", silence_logs=40)
    with cluster, distributed.Client(cluster) as client:
        yield client


@pytest.fixture(scope="session")
def loaded():
    """``loaded(*paths)``: ``gp.open(*paths, progressive=True)`` once its loader is done (it
    fails the test if the load does not finish in 2 minutes). The load's warnings are issued by
    its wait, so a ``pytest.warns`` around the call sees them."""

    def load(*paths):
        cloud = gp.open(*paths, progressive=True)
        assert cloud.wait(timeout=120)
        return cloud

    return load


@pytest.fixture
def gated_loading():
    """``load(strips, gates, name="survey", total=None)``: a progressive cloud ``name`` fed
    ``strips`` ((xyz, attributes) pairs; attributes a dict, or None for none) in turn as one
    source, each held until its gate of ``gates`` is set (a threading.Event, one gate may hold
    several strips; None: no wait), as a slow file; ``total``: the points it tells up front. Its
    gates are set and its clouds closed after."""
    from gigapoint.core.chunk import PointChunk
    from gigapoint.lod.progressive import Loader, ProgressiveOctree

    made = []

    def load(strips, gates, name="survey", total=None):
        def chunks():
            for (xyz, attributes), gate in zip(strips, gates, strict=True):
                if gate is not None:
                    gate.wait(60)
                yield PointChunk(xyz, attributes=attributes or {})

        cloud = ProgressiveOctree(name)
        made.append((cloud, gates))
        cloud.attach(Loader(cloud, [(name, chunks)], total).start())
        return cloud

    yield load
    for cloud, gates in made:
        for gate in gates:
            if gate is not None:
                gate.set()
        cloud.close()


@pytest.fixture
def strips_loading(gated_loading):
    """(xyz, cloud, go_on): 200 000 points over a 1000 x 1000 survey loading progressively west to
    east in strips of 20 000, held after the first strip until ``go_on`` is set (a viewer started
    on a file's first points); the cloud holds that strip when given, and is closed after."""
    import threading

    rng = np.random.default_rng(1)
    xyz = rng.uniform((0, 0, 0), (1000, 1000, 5), (200_000, 3))
    xyz = xyz[np.argsort(xyz[:, 0])]  # read in scan order: west to east
    go_on = threading.Event()
    strips = [(xyz[first : first + 20_000], None) for first in range(0, len(xyz), 20_000)]
    cloud = gated_loading(strips, [None] + [go_on] * (len(strips) - 1), name="strips", total=len(xyz))
    cloud.wait_first_points()
    return xyz, cloud, go_on


def pytest_report_header(config):
    import numba

    return f"gigapoint {gp.__version__}, numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads), GIGAPOINT_REGEN={os.environ.get('GIGAPOINT_REGEN', '0')}"
