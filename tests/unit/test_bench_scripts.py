"""Benchmark scripts' own helpers whose mistakes give wrong figures without an error: an A/B
whose base is secretly this revision, a PDAL grid one column off gigapoint's."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture
def scripts(monkeypatch):
    """benchmarks/ importable, as it is to the scripts themselves (their folder is sys.path[0]);
    gigapoint_base's modules forgotten afterwards."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    yield
    for name in [m for m in sys.modules if m == "gigapoint_base" or m.startswith("gigapoint_base.")]:
        del sys.modules[name]


def test_ab_base_draws_with_its_own_code(scripts, tmp_path):
    """gigapoint imports most names on first use, by absolute module names: the exported base
    must resolve them in itself, or bench_ab compares this revision with itself."""
    import bench_ab

    base = bench_ab.load_base("HEAD", tmp_path)
    assert base.render_frame.__module__ == "gigapoint_base.render.renderer"
    assert Path(base.render_frame.__code__.co_filename).is_relative_to(tmp_path)
    assert base.PointCloud is not gp.PointCloud and base.Camera is not gp.Camera
    assert importlib.import_module("gigapoint_base.lod").convert.__module__.startswith("gigapoint_base.")


@pytest.mark.parametrize("option", ["--points", "--lod-points", "--cap"])
def test_ab_bad_count_is_an_argparse_error_naming_its_option(scripts, capsys, option):
    """A bad --cap was said as a traceback naming --points."""
    import bench_ab

    with pytest.raises(SystemExit) as exit_:
        bench_ab.main(["--base", "HEAD", option, "x"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].endswith(f" error: {option}: cannot read 'x' (use e.g. 20M, 200k, 1e6 or 5000000)")

@pytest.mark.parametrize(
    ("script", "argv", "option"),
    [("bench_slices", ["load", "1M", "x"], "slices"), ("bench_progressive", ["--batch", "x"], "--batch"), ("gpu_exactness", ["--timing", "x"], "--timing")],
)
def test_a_bad_count_is_an_argparse_error_naming_its_option(scripts, capsys, script, argv, option):
    """A bad slice size, --batch or --timing was a traceback naming --points."""
    main = importlib.import_module(script).main
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].endswith(f" error: {option}: cannot read 'x' (use e.g. 20M, 200k, 1e6 or 5000000)")


@pytest.mark.parametrize(
    ("script", "argv", "option"),
    [
        ("bench_billion", ["--points", "x"], "--points"),
        ("bench_compact", ["--points", "x"], "--points"),
        ("bench_gis", ["--points", "x"], "--points"),
        ("bench_gpu_uploads", ["--points", "x"], "--points"),
        ("bench_render", ["--points", "1M", "x"], "--points"),
        ("bench_wgpu", ["--points", "x"], "--points"),
        ("gpu_early_depth", ["--points", "2M", "x"], "--points"),
        ("bench_small_batches", ["--sizes", "50,x"], "--sizes"),
        ("bench_live_small_frames", ["--sizes", "50,x"], "--sizes"),
        ("bench_first_look", ["--bands-ab", "--demo", "x"], "--demo"),
    ],
)
def test_every_scripts_bad_count_is_an_argparse_error_naming_its_option(script, argv, option):
    """These read their counts with their own int() or parse_count: a traceback, or exit status 1
    (and a bad second size only after the first size's minutes of work)."""
    env = dict(os.environ, PYTHONPATH=str(BENCHMARKS.parent / "src"))
    run = subprocess.run([sys.executable, str(BENCHMARKS / f"{script}.py"), *argv], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert [ln for ln in run.stderr.splitlines() if "error" in ln] == [run.stderr.splitlines()[-1]]
    assert run.stderr.splitlines()[-1].endswith(f" error: {option}: cannot read 'x' (use e.g. 20M, 200k, 1e6 or 5000000)")


def test_gis_dtm_grid_is_gigapoints_top_down_grid(scripts, tmp_path, points_las_writer):
    """PDAL's writers.gdal is given gigapoint's grid: Camera.top_down's, margins included (a
    ground point on a cell edge, x = 6, puts a column before it)."""
    import bench_gis

    xyz = np.array([[6.0, 6.0, 1.0], [10.5, 10.5, 2.0], [50.0, 50.0, 3.0]])
    classes = np.array([2, 2, 1], np.uint8)  # the class 1 point is not drawn
    las = points_las_writer(tmp_path / "g.las", xyz, np.zeros((3, 3), np.uint16), classification=classes)
    assert bench_gis.dtm_grid(las, 1.0) == (5.0, 5.0, 6, 6)
