"""`gigapoint compile`: compile every numba kernel once (numba caches them for later runs).

The first run after an install compiles the kernels it needs as it goes (cli/compiling.py
says so); this command does all of it up front, step by step with a progress bar: reading
LAS files, building clouds, every render pass and color mode, octrees, progressive loading
(a viewer's; with its big sets' variant, ``compile_wide_colour_sums``). Each step runs the
real code on a small scene, so exactly the kernels (and argument types) of real runs compile.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import typer

from ..core.kernel_cache import later_runs
from . import compiling
from .app import app
from .progress import err_console, progress_bar


def _las_file(folder: Path) -> Path:
    """A small LAS 1.2 file of point format 3 (RGB, intensity, classification...), as scanners write."""
    import laspy

    from ..io import demo_arrays

    xyz, rgba, _ = demo_arrays(20_000, seed=5)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.red, las.green, las.blue = (rgba[:, i].astype(np.uint16) * 256 for i in range(3))
    las.intensity = (np.arange(len(xyz)) % 4000).astype(np.uint16)
    las.classification = (np.arange(len(xyz)) % 7).astype(np.uint8)
    path = folder / "compile.las"
    las.write(path)
    return path


def compile_wide_colour_sums() -> None:
    """Compile ``kernels.sample_runs`` for sets of 2^24 points and more as well: the progressive
    octree sums their voxels' colours in u64, smaller ones' in u32 (``octree._voxel_cells``),
    and numba picks the variant by the sums' dtype, not their size, so a big set compiled it
    mid-load (seconds). Each u32 signature a load used, with its sums' array a u64 one."""
    import inspect

    import numba

    from ..lod.progressive import kernels

    at = list(inspect.signature(kernels.sample_runs.py_func).parameters).index("e_sum")
    for signature in list(kernels.sample_runs.signatures):
        if signature[at].dtype == numba.types.uint32:
            wide = signature[at].copy(dtype=numba.types.uint64)  # (its layout and dimensions as they are)
            kernels.sample_runs.compile((*signature[:at], wide, *signature[at + 1 :]))


def steps(folder: Path):
    """(name, function) of each step; a step may use what the ones before it made."""
    import gigapoint as gp

    made: dict = {}

    def read_las():
        made["las"] = gp.open(_las_file(folder))

    def build():
        made["demo"] = gp.demo(60_000, seed=1)

    def render(**settings):
        def run():
            for name in ("las", "demo"):
                cloud = made[name]
                for kw in settings.get("variants", [{}]):
                    s = gp.RenderSettings(backend="cpu", **{k: v for k, v in settings.items() if k != "variants"}, **kw)
                    cam = gp.Camera.fit_cloud(cloud, width=320, height=200)
                    gp.render_frame(cloud, cam, s)

        return run

    def colors():
        from ..render.settings import COLOR_MODES

        cloud = made["las"]
        gp.estimate_normals(cloud, k=8)
        cam = gp.Camera.fit_cloud(cloud, width=160, height=100)
        for kw in [{"color_mode": mode} for mode in COLOR_MODES if mode != "attribute"] + [{"lighting": True}]:  # (attribute: as intensity)
            gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", **kw))

    def octree():
        from ..io import demo_chunks
        from ..lod import convert

        out = folder / "octree"
        convert(list(demo_chunks(60_000, chunk_size=30_000)), out, max_leaf=8_000)
        convert([folder / "compile.las"], folder / "las_octree", max_leaf=8_000)  # compact nodes on a LAS grid, every field width
        for path in (out, folder / "las_octree"):
            oc = gp.open(path)
            gp.render_frame(oc, gp.Camera.fit_cloud(oc, width=320, height=200), gp.RenderSettings(backend="cpu"))

    def progressive():
        gp.demo(120_000, progressive=True).wait()  # (more points than a leaf holds: inner nodes' voxels are sampled)
        compile_wide_colour_sums()

    return [
        ("the demo scene", build),
        ("reading LAS/LAZ files", read_las),
        ("rendering", render(variants=[{}, {"size_mode": "fixed"}, {"threads": 1}, {"max_points": 20_000}, {"stereo": "anaglyph"}])),
        ("point sizes", render(variants=[{"point_size": 3, "point_shape": "round"}, {"size_mode": "attenuated", "point_world_size": 2.0}])),
        ("eye-dome lighting", render(edl=True)),
        ("hole filling", render(fill_holes=1, size_mode="fixed")),
        ("high-quality shading", render(hqs=True, variants=[{}, {"point_size": 3, "splat_softness": 2.0}])),
        ("supersampling", render(supersample=2)),
        ("color modes and lighting", colors),
        ("octrees", octree),
        ("progressive loading", progressive),
    ]


@app.command("compile")
def compile_kernels() -> None:
    """Compile every numba kernel now (a minute or two, once per install), instead of on first use."""
    watch = compiling.current()
    console = err_console()
    t0 = time.perf_counter()
    report = []
    with tempfile.TemporaryDirectory(prefix="gigapoint-compile-") as tmp:
        todo = steps(Path(tmp))
        with progress_bar("compiling", len(todo), console) as advance:
            for i, (name, run) in enumerate(todo):
                advance(i, name)
                seconds, kernels = (watch.seconds, watch.kernels) if watch is not None else (0.0, 0)
                run()
                if watch is not None:
                    seconds, kernels = watch.seconds - seconds, watch.kernels - kernels
                report.append((name, kernels, seconds))
            advance(len(todo))
    total = sum(s for _, _, s in report)
    for name, kernels, spent in report:
        typer.echo(f"  {name:28} {f'compiled in {spent:.1f} s' if kernels else 'cached'}")
    if any(kernels for _, kernels, _ in report):
        typer.echo(f"compiled the kernels in {total:.0f} s ({time.perf_counter() - t0:.0f} s in all); {later_runs()}")
    else:
        typer.echo(f"every kernel was compiled already ({time.perf_counter() - t0:.1f} s)")
    if watch is not None:
        watch.enabled = False  # its closing line would repeat ours
