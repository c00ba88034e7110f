"""Conversion throughput (points/s) and peak memory per sampler, demo scene as LAS input.

    .venv/bin/python benchmarks/bench_convert.py --points 2000000 [--samplers grid,poisson] [--memory-limit 2G] [--input laz]

Each conversion runs in its own child process; its peak memory is the child's maxrss
(os.wait4). ``--input laz`` converts the same points from a LAZ copy (made once with laspy). A tiny conversion first fills numba's cache so JIT compile time is excluded.
Reference (PotreeConverter 2 on the project machine, 20 M points LAS): 1.7 M points/s
poisson, 2.5 M points/s random. PotreeConverter shows nothing before it finishes; ``first_view_s``
is when gigapoint's output first opened (its preview, lod/preview.py).

``--potree-converter PATH`` measures a PotreeConverter 2 binary in the same run, on the same
file, alternating with gigapoint run by run (grid is compared with its ``--method random``,
poisson with ``--method poisson``): process wall time and peak memory of both, the ratio, and
a check that its metadata.json holds every point.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from gigapoint.bench import run_measured

CHILD = """
import json, sys, time
from gigapoint.core.threads import skip_blas_check
from gigapoint.lod import convert
skip_blas_check()  # as `gigapoint convert` does (cli.main)
args = json.loads(sys.argv[1])
t = time.perf_counter()
r = convert([args["input"]], args["out"], sampler=args["sampler"], memory_limit=args["memory_limit"], format=args["format"])
print(json.dumps({"points": r.points, "nodes": r.nodes, "seconds": time.perf_counter() - t, "phases": r.phase_seconds, "first_view": r.first_view_seconds}))
from gigapoint.cli import exit_without_teardown
exit_without_teardown(0)  # as `gigapoint convert` ends (cli.run): the interpreter's teardown took 0.3 s of the process
"""


def write_las(path: Path, n: int, scale: float = 0.001) -> Path:
    """The demo town's first ``n`` points as a LAS 1.2 file (point format 3) at ``scale`` metres, in chunks."""
    import laspy

    from gigapoint.io import demo_chunks

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [scale] * 3
    header.offsets = [0.0, 0.0, 0.0]
    with laspy.open(str(path), mode="w", header=header) as writer:
        for chunk in demo_chunks(n, chunk_size=1_000_000):
            rec = laspy.ScaleAwarePointRecord.zeros(len(chunk), header=header)
            rec.x, rec.y, rec.z = chunk.xyz[:, 0], chunk.xyz[:, 1], chunk.xyz[:, 2]
            rgb = chunk.rgba[:, :3].astype(np.uint16) * 257
            rec.red, rec.green, rec.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
            rec.intensity = chunk.attributes["intensity"]
            rec.classification = chunk.attributes["classification"]
            writer.write_points(rec)
    return path


def demo_las_in(workdir: str | None, n: int, prefix: str) -> tuple[Path, Path]:
    """(work directory, the demo scene's first n points as a LAS file in it, written once);
    without ``workdir`` a new temporary directory."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix=prefix))
    work.mkdir(parents=True, exist_ok=True)
    las = work / f"demo_{n}.las"
    if not las.exists():
        write_las(las, n)
    return work, las


def write_laz(las: Path, laz: Path) -> None:
    import laspy

    tmp = laz.with_name(laz.name + ".tmp")
    with laspy.open(str(las)) as reader, laspy.open(str(tmp), mode="w", header=reader.header, do_compress=True) as writer:
        for pts in reader.chunk_iterator(1_000_000):
            writer.write_points(pts)
    tmp.rename(laz)


def run_child(args: dict) -> tuple[dict, float, int]:
    """(the conversion's report, wall seconds, peak RSS bytes: gigapoint.bench.run_measured)."""
    code, out, err, wall, peak = run_measured([sys.executable, "-c", CHILD, json.dumps(args)])
    if code != 0:
        raise SystemExit(f"conversion failed ({code}): {err.decode()[-2000:]}")
    return json.loads(out.decode().strip().splitlines()[-1]), wall, peak


def run_potree(binary: str, las: Path, out: Path, method: str) -> tuple[float, int]:
    """(wall seconds, peak RSS bytes) of one PotreeConverter run; its output must hold every point."""
    shutil.rmtree(out, ignore_errors=True)
    code, _, err, wall, peak = run_measured([binary, str(las), "-o", str(out), "--method", method])
    if code != 0 or not (out / "metadata.json").is_file():
        raise SystemExit(f"PotreeConverter failed: {err.decode(errors='replace')[-2000:]}")
    return wall, peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--samplers", default="grid,poisson")
    ap.add_argument("--memory-limit", default=None)
    ap.add_argument("--format", default="gigapoint")
    ap.add_argument("--input", choices=("las", "laz"), default="las", help="input file format (LAZ: the same points compressed)")
    ap.add_argument("--workdir", default=None, help="keep the LAS file and outputs here")
    ap.add_argument("--repeat", type=int, default=1, help="runs per sampler; the fastest is reported (shared machines are noisy)")
    ap.add_argument("--potree-converter", default=None, help="a PotreeConverter 2 binary to measure in the same run (alternating)")
    a = ap.parse_args()
    work, las = demo_las_in(a.workdir, a.points, "bench_convert_")
    warm = work / "warm.las"
    if not warm.exists():
        write_las(warm, 20_000)
    if a.input == "laz":
        las = las.with_suffix(".laz")
        if not las.exists():
            write_laz(las.with_suffix(".las"), las)
        warm_laz = warm.with_suffix(".laz")
        if not warm_laz.exists():
            write_laz(warm, warm_laz)
        warm = warm_laz
    results = []
    try:
        for sampler in a.samplers.split(","):
            run_child(
                {"input": str(warm), "out": str(work / "warm_out"), "sampler": sampler, "memory_limit": a.memory_limit, "format": a.format}
            )
            shutil.rmtree(work / "warm_out", ignore_errors=True)
            out = work / f"out_{sampler}"
            best, potree = None, None
            method = "random" if sampler == "grid" else "poisson"  # PotreeConverter's nearest sampler
            for _ in range(a.repeat):
                shutil.rmtree(out, ignore_errors=True)
                run = run_child(
                    {"input": str(las), "out": str(out), "sampler": sampler, "memory_limit": a.memory_limit, "format": a.format}
                )
                if best is None or run[0]["seconds"] < best[0]["seconds"]:
                    best = run
                if a.potree_converter:
                    pc = run_potree(a.potree_converter, las, work / "out_potree", method)
                    meta = json.loads((work / "out_potree" / "metadata.json").read_text())
                    if int(meta["points"]) != run[0]["points"]:
                        raise SystemExit(f"PotreeConverter wrote {meta['points']} points, gigapoint {run[0]['points']}")
                    potree = pc if potree is None or pc[0] < potree[0] else potree
                    shutil.rmtree(work / "out_potree", ignore_errors=True)
            info, wall, rss = best
            row = {
                "input": a.input,
                "sampler": sampler,
                "points": info["points"],
                "nodes": info["nodes"],
                "convert_s": round(info["seconds"], 3),
                "first_view_s": round(info["first_view"], 3),  # until OUT/.partial/preview.npz could be viewed
                "process_s": round(wall, 3),
                "points_per_s": round(info["points"] / info["seconds"]),
                "process_points_per_s": round(info["points"] / wall),
                "peak_rss_mib": round(rss / 2**20, 1),
                "phases_s": info["phases"],
            }
            if potree is not None:
                row.update(
                    potree_method=method,
                    potree_process_s=round(potree[0], 3),
                    potree_points_per_s=round(info["points"] / potree[0]),
                    potree_peak_rss_mib=round(potree[1] / 2**20, 1),
                    speedup_vs_potree=round(potree[0] / wall, 2),  # process wall times, both with start-up
                )
            results.append(row)
            print(json.dumps(row))
            shutil.rmtree(out, ignore_errors=True)
    finally:
        if not a.workdir:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
