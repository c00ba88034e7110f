"""The render benchmark: result structure, sane figures, and a GL baseline that draws the same thing."""

from __future__ import annotations

import json
import math
import os
import re

import numpy as np
import pytest

import gigapoint
from gigapoint.bench import (
    COVERAGE_TOLERANCE,
    benchmark_cameras,
    demo_cloud,
    gl_matrix,
    naive_frame,
    naive_matrix,
    parse_count,
    parse_threads,
    results_table,
    run_render_benchmark,
    write_results,
)
from gigapoint.errors import GigapointError

N = 200_000
W, H = 320, 240


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    return run_render_benchmark(points=(N,), width=W, height=H, threads=(1, None), repeats=1, out=out), out


def test_result_structure_and_figures(bench_run):
    results, _ = bench_run
    kinds = [r["kind"] for r in results]
    assert kinds[0] == "environment" and "points in the cloud" in results[0]["definition"]
    gen = next(r for r in results if r["kind"] == "generate")
    build = next(r for r in results if r["kind"] == "build")
    assert gen["points"] == N and gen["points_per_second"] > 0 and gen["seconds"] > 0
    assert build["batches"] == math.ceil(N / gigapoint.core.BATCH_SIZE) and build["seconds"] > 0
    renders = [r for r in results if r["kind"] == "render" and r["renderer"] == "gigapoint"]
    assert {(r["view"], r["threads"] == 1) for r in renders} == {
        ("overview", True),
        ("overview", False),
        ("closeup", True),
        ("closeup", False),
    }
    for r in renders:
        assert r["points_per_second"] > 0
        assert r["points_per_second"] == pytest.approx(N / (r["frame_ms"] / 1e3))  # points in the cloud / frame time
        assert len(r["frame_ms_runs"]) == 1 and 0 < r["raster_ms"] <= r["frame_ms"]
        assert r["batches_culled"] + r["batches_rendered"] == r["batches_total"] == build["batches"]
        assert sum(r["precision_histogram"].values()) == r["points_processed"]
        assert 0 < r["coverage"] < 1
    by_view = {r["view"]: r for r in renders}
    # the overview frames the whole scene; the close-up culls what is behind it and needs more than 10 bits nearby
    assert by_view["overview"]["batches_culled"] == 0 and by_view["overview"]["points_processed"] == N
    assert by_view["closeup"]["batches_culled"] > 0
    h = by_view["closeup"]["precision_histogram"]
    assert h["20"] + h["30"] > 0 and h["10"] > 0
    json.dumps(results)  # everything is plain JSON


def test_gl_baseline_ran_and_matches_or_was_skipped(bench_run):
    results, out = bench_run
    gl_rows = [r for r in results if r["kind"] == "render" and r["renderer"] == "gl"]
    assert [r["view"] for r in gl_rows] == ["overview", "closeup"]
    for r in gl_rows:
        if r["skipped"]:
            assert r["reason"] and results[0]["gl_skipped_reason"] == r["reason"]
            continue
        assert r["points_per_second"] > 0 and r["gigapoint_over_gl"] > 0
        assert abs(r["coverage"] - r["coverage_gigapoint"]) <= COVERAGE_TOLERANCE
        assert r["coverage_matches"] and r["coverage_iou"] > 0.9
        assert (out / f"gl_{N}_{r['view']}.png").is_file()
    for view in ("overview", "closeup"):
        assert (out / f"gigapoint_{N}_{view}.png").is_file()


def test_naive_baseline_rows(bench_run):
    results, out = bench_run
    rows = [r for r in results if r["kind"] == "render" and r["renderer"] == "naive"]
    assert [r["view"] for r in rows] == ["overview", "closeup"]
    gigapoint = [r for r in results if r["kind"] == "render" and r["renderer"] == "gigapoint"]
    for r in rows:
        best = max((g for g in gigapoint if g["view"] == r["view"]), key=lambda g: g["threads"])  # what the loop is compared with
        assert r["threads"] == best["threads"] and r["points_per_second"] == pytest.approx(N / (r["frame_ms"] / 1e3))
        assert 0 < r["raster_ms"] <= r["frame_ms"] and len(r["frame_ms_runs"]) == 1
        assert r["gigapoint_over_naive"] == pytest.approx(best["points_per_second"] / r["points_per_second"])
        # the same points and view: the same pixels covered (float32 positions against 10/20/30-bit batches)
        assert abs(r["coverage"] - best["coverage"]) <= COVERAGE_TOLERANCE and r["coverage_iou"] > 0.9
        assert (out / f"naive_{N}_{r['view']}.png").is_file()
    assert "naive loop" in _table_text(results)


def test_no_naive_skips_it():
    results = run_render_benchmark(points=(20_000,), width=64, height=48, threads=(1,), repeats=1, gl=False, naive=False, views=("overview",))
    assert not [r for r in results if r.get("renderer") == "naive"]


@pytest.mark.parametrize("threads", [1, 2])
def test_naive_loop_is_the_plain_per_point_min(threads):
    """naive_frame == a numpy transcription of the loop (same float32 operations, np.minimum.at
    per pixel), whatever the thread count; points behind, beside or beyond the frustum drop out."""
    bounds = (np.array([0.0, 0.0, 0.0]), np.array([100.0, 80.0, 30.0]))
    cam = benchmark_cameras(bounds, 96, 64)["closeup"]
    near, far = cam.clip_range(bounds)
    center = (bounds[0] + bounds[1]) / 2
    rng = np.random.default_rng(1)
    xyz = (rng.random((50_000, 3)) * (bounds[1] - bounds[0]) + bounds[0] - center).astype(np.float32)
    xyz[::7] = xyz[3::7][: len(xyz[::7])]  # repeated positions: ties go to the lower index
    color = rng.integers(0, 2**32, len(xyz), dtype=np.uint64).astype(np.uint32)
    vis, colors, seconds = naive_frame(xyz, color, cam, near, far, threads, (1, 2, 3, 255), center)
    m = naive_matrix(cam, center)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    sx, sy, sw, sd = (m[r, 0] * x + m[r, 1] * y + m[r, 2] * z + m[r, 3] for r in range(4))
    with np.errstate(divide="ignore", invalid="ignore"):
        px, py = sx / sw, sy / sw
    keep = (sw > 0) & (sd > np.float32(near)) & (sd < np.float32(far)) & (px >= 0) & (px < cam.width) & (py >= 0) & (py < cam.height)
    assert 0 < keep.sum() < len(xyz)  # some points are outside the view
    idx = np.flatnonzero(keep)
    pix = py[keep].astype(np.int64) * cam.width + px[keep].astype(np.int64)
    keys = (sd[keep].view(np.uint32).astype(np.uint64) << np.uint64(32)) | idx.astype(np.uint64)
    ref = np.full(cam.width * cam.height, np.uint64(2**64 - 1))
    np.minimum.at(ref, pix, keys)
    np.testing.assert_array_equal(vis, ref)
    bg = np.array([1, 2, 3, 255], np.uint8).view(np.uint32)[0]
    hit = ref != np.uint64(2**64 - 1)
    np.testing.assert_array_equal(colors[hit], color[(ref[hit] & np.uint64(0xFFFFFFFF)).astype(np.int64)])
    assert (colors[~hit] == bg).all() and seconds > 0


def _table_text(results) -> str:
    from rich.console import Console

    console = Console(record=True, width=240)
    console.print(results_table(results))
    return console.export_text()


def test_table_and_json(bench_run, tmp_path):
    results, _ = bench_run
    text = _table_text(results)
    assert "closeup" in text and "generate" in text and "Morton sort" in text
    path = write_results(results, tmp_path / "r.json")
    assert json.loads(path.read_text()) == json.loads(json.dumps(results))
    made = write_results(results, tmp_path / "new" / "dir" / "r.json")  # its missing folders made
    assert made == tmp_path / "new" / "dir" / "r.json" and json.loads(made.read_text()) == json.loads(path.read_text())
    with pytest.raises(GigapointError, match=f"^{re.escape(str(path / 'r.json'))}: {re.escape(str(path))} is a file, not a folder$"):
        write_results(results, path / "r.json")


def test_demo_cloud_is_gigapoint_demo():
    timings: dict = {}
    mine = demo_cloud(30_000, seed=3, timings=timings)
    ref = gigapoint.demo(30_000, seed=3, scale=None)
    assert timings["generate_s"] > 0 and timings["build_s"] > 0
    for name in ("low", "med", "high", "color"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(ref, name))
    np.testing.assert_array_equal(mine.batches, ref.batches)


@pytest.mark.parametrize("view", ["overview", "closeup"])
def test_gl_matrix_projects_like_gigapoint(view):
    """GL window coordinates of centre-relative points == gigapoint's pixel coordinates; depth maps near/far to -1/1."""
    bounds = (np.array([1000.0, 2000.0, -15.0]), np.array([2000.0, 3000.0, 60.0]))
    cam = benchmark_cameras(bounds, W, H)[view]
    near, far = cam.clip_range(bounds)
    center = (bounds[0] + bounds[1]) / 2
    rng = np.random.default_rng(0)
    world = bounds[0] + rng.random((500, 3)) * (bounds[1] - bounds[0])
    p = np.c_[world, np.ones(len(world))] @ cam.screen_rows().T
    front = p[:, 2] > 0
    clip = np.c_[world - center, np.ones(len(world))] @ gl_matrix(cam, near, far, center).T
    ndc = clip[front, :3] / clip[front, 3:4]
    np.testing.assert_allclose((ndc[:, 0] + 1) / 2 * W, p[front, 0] / p[front, 2], rtol=0, atol=1e-6)
    np.testing.assert_allclose((ndc[:, 1] + 1) / 2 * H, p[front, 1] / p[front, 2], rtol=0, atol=1e-6)
    for d, z in ((near, -1.0), (far, 1.0)):
        on_plane = cam.eye + d * (-cam.basis()[2])  # a point at depth d on the view axis
        c = np.r_[on_plane - center, 1.0] @ gl_matrix(cam, near, far, center).T
        assert c[2] / c[3] == pytest.approx(z, abs=1e-9)


def test_parsers_and_bad_input(tmp_path, capsys):
    assert parse_count("20M") == 20_000_000 and parse_count("200k") == 200_000 and parse_count("1e6") == 1_000_000
    assert parse_count("5_000_000") == 5_000_000
    assert parse_threads("all") is None and parse_threads("2") == 2
    for bad in ("abc", "0", "-5", "1.5"):
        with pytest.raises(GigapointError, match="--points"):
            parse_count(bad)
    with pytest.raises(GigapointError, match="--threads"):
        parse_threads("x")
    with pytest.raises(GigapointError, match="repeats"):
        run_render_benchmark(points=(1000,), repeats=0, gl=False)
    with pytest.raises(GigapointError, match="points"):
        run_render_benchmark(points=(0,), gl=False)
    afile = tmp_path / "f"
    afile.write_text("x")
    with pytest.raises(GigapointError, match="directory"):
        run_render_benchmark(points=(1000,), out=afile, gl=False)
    # refused before any scene is made (they were found minutes into a run: out of memory, or
    # once every measurement was made: the JSON's folder)
    with pytest.raises(GigapointError, match=r"^benchmark of 10,000,000,000,000 points: .* take 480.0 TB or more, .*: measure fewer --points$"):
        run_render_benchmark(points=(1000, 10**13), gl=False)
    from gigapoint.cli import main

    capsys.readouterr()
    # a path through a file: refused before anything is measured
    assert main(["bench", "-n", "1000", "--json", str(afile / "sub" / "r.json"), "--no-gl", "--no-naive"]) == 1
    out, err = capsys.readouterr()
    assert err == f"error: {afile / 'sub' / 'r.json'}: {afile} is a file, not a folder\n" and "points/s" not in out  # nothing measured
    assert afile.read_text() == "x"
    scan = tmp_path / "scan.laz"  # --json scan.laz replaced the user's file with the results, without a word
    scan.write_bytes(b"precious")
    results = tmp_path / "r.json"
    results.write_text("[]")
    for path, problem in ((scan, "unsupported output type '.laz'; use one of .json"), (results, "already exists; pass --overwrite to replace it")):
        assert main(["bench", "-n", "1000", "--json", str(path), "--no-gl", "--no-naive", "--repeats", "1"]) == 1
        out, err = capsys.readouterr()
        assert err == f"error: {path}: {problem}\n" and "points/s" not in out
    assert scan.read_bytes() == b"precious" and results.read_text() == "[]"
    assert main(["bench", "-n", "1000", "--json", str(results), "--no-gl", "--no-naive", "--repeats", "1", "--threads", "1", "--overwrite"]) == 0
    assert json.loads(results.read_text())[0]["kind"] == "environment"
    made = tmp_path / "nowhere" / "yet" / "r.json"  # the folders missing on its way are made as it is written (were refused at the start)
    assert main(["bench", "-n", "1000", "--json", str(made), "--no-gl", "--no-naive", "--repeats", "1", "--threads", "1"]) == 0
    assert json.loads(made.read_text())[0]["kind"] == "environment"


def test_no_gl_reports_skipped():
    results = run_render_benchmark(points=(20_000,), width=64, height=48, threads=(1,), repeats=1, gl=False, views=("overview",))
    gl_rows = [r for r in results if r.get("renderer") == "gl"]
    assert len(gl_rows) == 1 and gl_rows[0]["skipped"] and "no-gl" in gl_rows[0]["reason"]


@pytest.mark.parametrize("broken", ["no_module", "no_context"])
def test_gl_unavailable_is_reported_not_raised(monkeypatch, broken):
    import sys
    import types

    if broken == "no_module":
        monkeypatch.setitem(sys.modules, "moderngl", None)  # import fails
        expected = "moderngl"
    else:
        fake = types.ModuleType("moderngl")

        def no_context(**kw):
            raise RuntimeError("eglInitialize failed\nmore detail")

        fake.create_standalone_context = no_context
        monkeypatch.setitem(sys.modules, "moderngl", fake)
        expected = "eglInitialize failed"
    results = run_render_benchmark(points=(20_000,), width=64, height=48, threads=(1,), repeats=1, views=("closeup",))
    gl_rows = [r for r in results if r.get("renderer") == "gl"]
    assert len(gl_rows) == 1 and gl_rows[0]["skipped"]
    assert expected in gl_rows[0]["reason"] and "\n" not in gl_rows[0]["reason"]
    assert results[0]["gl_renderer"] is None
    assert any(r.get("renderer") == "gigapoint" and r["points_per_second"] > 0 for r in results)


def test_coverage_iou_of_two_masks():
    from gigapoint.bench import coverage_iou

    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert coverage_iou(a, b) == 1.0  # both empty
    a[0, :] = True  # 4 pixels
    b[0, :2] = True
    b[1, 0] = True  # 3 pixels, 2 shared: IoU 2 / 5
    assert coverage_iou(a, b) == 0.4
    assert coverage_iou(a, ~a) == 0.0


def test_cpu_model_names_the_processor(monkeypatch):
    """Every benchmark states the CPU (the machine changes between sessions): lscpu's model
    name, or the platform's, never an empty string."""
    import subprocess

    from gigapoint.bench import cpu_model

    class Done:
        stdout = "Architecture:        x86_64\nModel name:          Some CPU 9000\n"

    monkeypatch.setattr(subprocess, "run", lambda *a, **k: Done())
    assert cpu_model() == "Some CPU 9000"

    def missing(*a, **k):
        raise FileNotFoundError("lscpu")

    monkeypatch.setattr(subprocess, "run", missing)
    assert cpu_model()  # the platform's name, or "unknown CPU"


@pytest.mark.skipif(not os.path.exists("/proc/vmstat"), reason="Linux's /proc/vmstat")
def test_machine_pages_counts_the_memory_a_run_touches():
    """bench_dask / bench_live print the new pages a run needed (this VM's host faults them in
    slowly): 96 MB touched in this process is at least 96 MB more of them."""
    from gigapoint.bench import machine_pages, pages_since

    before = machine_pages()
    assert before[0] > 0 and before[1] >= 0
    touched = np.ones(12 << 20)  # 96 MiB of float64, every page written
    grew = pages_since(before)
    assert touched.nbytes / 2**20 <= grew["alloc_mib"] < 100_000
    assert grew["reported_mib"] >= 0


def test_a_childs_peak_memory_is_its_own_not_the_benchmarks():
    """run_measured reports the command's peak RSS: not the high-water mark of the (large)
    process that started it, which Linux hands a child across exec as its ru_maxrss."""
    import sys

    from gigapoint.bench import run_measured

    held = np.ones(50_000_000)  # 400 MB held (and touched) by the benchmark
    code, out, _, wall, small = run_measured([sys.executable, "-c", "print('hi')"])
    assert code == 0 and out.strip() == b"hi" and wall > 0 and small < 200 * 2**20
    code, _, _, _, large = run_measured([sys.executable, "-c", "import numpy as np; a = np.ones(40_000_000); print(a.sum())"])
    assert code == 0 and 320 * 2**20 < large < 600 * 2**20  # its 320 MB, not the benchmark's 400 MB on top
    assert run_measured([sys.executable, "-c", "raise SystemExit(3)"])[0] == 3
    del held
