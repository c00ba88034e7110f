"""The conversion on Dask (lod/convert/distributed.py): speed-up on N single-threaded workers,
against the single-process (multithreaded) converter, and the scheduler's cost per task.

    .venv/bin/python benchmarks/bench_dask.py --points 20000000 --workdir /tmp/bd --rounds 3
    .venv/bin/python benchmarks/bench_dask.py --overhead-tasks 1000,10000,100000 --skip-convert

Each conversion runs in its own child process, in rounds that alternate the configurations
(single process, 1 worker, 2 workers, ...), so that load from elsewhere on the machine falls on
all of them alike; the table gives each configuration's fastest run and each round's ratios.
A child first converts a small file (numba's caches, the workers' imports), then times
``convert()`` of the demo scene as LAS (bench_convert.py writes it once). A Dask child starts
the LocalCluster ``--workers N`` starts (distributed.open_client: N single-threaded worker
processes, ``NUMBA_NUM_THREADS=1``, ``MALLOC_ARENA_MAX=1``, no Dask profiler) before the
clock starts, and records every task's compute time (``distributed.get_task_stream``): tasks per kind, compute seconds, the mean per task.

``--overhead-tasks`` measures the scheduler's cost per task with metadata-only tasks: the
converter's own task wrapper around a function that returns a read task's small result dict,
submitted and collected by the driver's loop, on a LocalCluster of ``--overhead-workers``
workers; seconds per task = wall / tasks, and the per-task overhead a conversion of T tasks pays.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_convert import demo_las_in  # the demo scene as LAS, written once

CHILD = r"""
import json, os, shutil, sys, time
from pathlib import Path
from gigapoint.lod import convert

from gigapoint.bench.report import machine_pages, pages_since  # new memory: this VM's host faults it in slowly

def main():
    a = json.loads(sys.argv[1])
    work = Path(a["work"])
    opts = dict(sampler=a["sampler"], memory_limit=a["memory_limit"])
    if a["workers"] == 0:
        shutil.rmtree(work / "warm0", ignore_errors=True)
        convert([a["small"]], work / "warm0", **opts)
        out = work / "out0"
        shutil.rmtree(out, ignore_errors=True)
        pages, t = machine_pages(), time.perf_counter()
        r = convert([a["input"]], out, **opts)
        print(json.dumps({"seconds": time.perf_counter() - t, "phases": r.phase_seconds, "nodes": r.nodes, "points": r.points, "pages": pages_since(pages)}))
        return
    from distributed import get_task_stream
    from gigapoint.lod.convert.distributed import open_client
    t = time.perf_counter()
    with open_client(a["workers"]) as client:  # the LocalCluster `gigapoint convert --workers N` starts
        startup = time.perf_counter() - t
        out = work / f"warm{a['workers']}"
        shutil.rmtree(out, ignore_errors=True)
        convert([a["small"]], out, client=client, **opts)
        out = work / f"out{a['workers']}"
        shutil.rmtree(out, ignore_errors=True)
        with get_task_stream(client) as stream:
            pages, t, cpu = machine_pages(), time.perf_counter(), time.process_time()
            r = convert([a["input"]], out, client=client, **opts)
            seconds, cpu = time.perf_counter() - t, time.process_time() - cpu  # this process: driver, client and scheduler
            pages = pages_since(pages)
        tasks = {}
        for d in stream.data:
            kind = str(d["key"]).split("-")[3]
            compute = sum(s["stop"] - s["start"] for s in d["startstops"] if s["action"] == "compute")
            k = tasks.setdefault(kind, [0, 0.0])
            k[0] += 1
            k[1] += compute
        def maxrss():
            import resource
            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        rss = sorted(client.run(maxrss).values())
        print(json.dumps({"seconds": seconds, "phases": r.phase_seconds, "nodes": r.nodes, "points": r.points,
                          "startup": startup, "tasks": tasks, "worker_peak_rss": rss, "driver_cpu": cpu, "pages": pages}))

if __name__ == "__main__":
    main()
"""

OVERHEAD_CHILD = r"""
import json, os, sys, time
from pathlib import Path

def meta(spec, i):  # what a read task returns, without reading anything
    return {"chunks": 1, "input": i, "points": i, "skipped": 0, "lo": [0.0, 0.0, 0.0], "hi": [1.0, 1.0, 1.0],
            "attributes": {"intensity": "<u2"}, "ends16": False, "eight": False}

def main():
    a = json.loads(sys.argv[1])
    from distributed import Client, LocalCluster
    from gigapoint.lod import OctreeDir
    from gigapoint.lod.convert.distributed import DaskPhases
    cluster = LocalCluster(n_workers=a["workers"], threads_per_worker=1, processes=True, dashboard_address=":0",
                           env={"NUMBA_NUM_THREADS": "1"}, silence_logs=40)
    client = Client(cluster)
    # the driver's task loop (DaskPhases._run: submit, as_completed, results) without a conversion around it
    d = object.__new__(DaskPhases)
    d.client, d.out, d.sampler, d.format, d.max_leaf, d.encoding = client, Path("/nonexistent"), "grid", "gigapoint", 20000, "DEFAULT"
    d.dir = OctreeDir(d.out)
    d.chunk_size, d.mem, d._out_tag, d._run_tag, d._tasks_run = 2_000_000, 1 << 30, "bench", os.urandom(4).hex(), 0
    d.paths, d.one_angle, d.point_filter, d.reprojection, d.colorization = [Path("/nonexistent.las")], False, None, None, None
    d.state = {"origin": [0.0, 0.0, 0.0], "edge": 1.0, "attributes": {"intensity": "<u2"}, "run": "bench"}
    # the spec every task carries, less the run token: with it each worker would first check the
    # output folder the driver writes (_worker_checked), and this run writes none
    spec = DaskPhases._spec(d)
    del spec["run"]
    d._spec = lambda: spec
    try:
        d._run("meta", [(f"w{i}", meta, (i,), 0) for i in range(20)], lambda i, r: None)
        rows = []
        for n in a["tasks"]:
            got = []
            t = time.perf_counter()
            d._run("meta", [(f"t{i}", meta, (i,), 0) for i in range(n)], lambda i, r: got.append(r["points"]))
            wall = time.perf_counter() - t
            assert len(got) == n
            rows.append({"tasks": n, "wall": wall, "per_task_ms": 1000 * wall / n})
        print(json.dumps(rows))
    finally:
        client.close()
        cluster.close()

if __name__ == "__main__":
    main()
"""


def run_child(code: str, args: dict, timeout: float = 3600) -> dict:
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(args)], check=False, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"child failed ({proc.returncode}): {proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def cpu_model() -> str:
    from gigapoint.bench import cpu_model

    return f"{cpu_model()}, {os.cpu_count()} CPUs"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20_000_000)
    ap.add_argument("--workers", default="1,2", help="worker counts to compare with the single process")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--sampler", default="grid")
    ap.add_argument("--memory-limit", default=None)
    ap.add_argument("--workdir", default=None, help="keeps the LAS input between runs")
    ap.add_argument("--skip-convert", action="store_true")
    ap.add_argument("--overhead-tasks", default="", help="e.g. 1000,10000,100000: metadata-only tasks on a LocalCluster")
    ap.add_argument("--overhead-workers", type=int, default=2)
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args()
    print(f"CPU: {cpu_model()}; Python {platform.python_version()}")
    results: dict = {"cpu": cpu_model()}
    if not a.skip_convert:
        work, las = demo_las_in(a.workdir, a.points, "gp_bench_dask_")
        _, small = demo_las_in(str(work), 200_000, "gp_bench_dask_")
        configs = [0, *(int(w) for w in a.workers.split(","))]
        runs: dict[int, list] = {c: [] for c in configs}
        for r in range(a.rounds):
            order = configs if r % 2 == 0 else configs[::-1]  # the order flips every round
            for c in order:
                args = {"work": str(work), "input": str(las), "small": str(small), "workers": c, "sampler": a.sampler, "memory_limit": a.memory_limit}
                res = run_child(CHILD, args)
                runs[c].append(res)
                name = "single process" if c == 0 else f"{c} worker{'s' if c > 1 else ''}"
                extra = f", cluster start {res['startup']:.1f} s" if c else ""
                fresh = f"; pages allocated {res['pages']['alloc_mib']:.0f} MiB, given back to the host {res['pages']['reported_mib']:.0f} MiB"
                print(f"round {r + 1}: {name}: {res['seconds']:.2f} s ({a.points / res['seconds'] / 1e6:.2f} M points/s){extra}; {res['phases']}{fresh}")
            row = {c: runs[c][-1]["seconds"] for c in configs}
            ratios = ", ".join(f"{c}w/single {row[c] / row[0]:.2f}" for c in configs[1:])
            if 1 in row and 2 in row:
                ratios += f", speed-up 2w vs 1w {row[1] / row[2]:.2f}"
            print(f"round {r + 1} ratios: {ratios}")
        print()
        print("| configuration | best convert() | M points/s | tasks (kind: n, compute s) | compute / (workers x wall) |")
        print("|---|---|---|---|---|")
        for c in configs:
            best = min(runs[c], key=lambda x: x["seconds"])
            if c == 0:
                print(f"| single process (numba threads: all cores) | {best['seconds']:.2f} s | {a.points / best['seconds'] / 1e6:.2f} | | |")
                continue
            tasks = best["tasks"]
            compute = sum(v[1] for v in tasks.values())
            desc = ", ".join(f"{k}: {v[0]}, {v[1]:.2f}" for k, v in tasks.items())
            print(f"| {c} worker(s) | {best['seconds']:.2f} s | {a.points / best['seconds'] / 1e6:.2f} | {desc} | {compute / (c * best['seconds']):.2f} |")
            print(f"|  | workers' peak memory (maxrss) | {', '.join(f'{r / 2**20:.0f} MiB' for r in best['worker_peak_rss'])} | "
                  f"driver + scheduler CPU: {best['driver_cpu']:.2f} s | |")
        best = {c: min(r["seconds"] for r in runs[c]) for c in configs}
        if 1 in best and 2 in best:
            print(f"\nbest of each: 2 workers vs 1: {best[1] / best[2]:.2f}x (efficiency {best[1] / best[2] / 2:.2f}); 2 workers / single process: {best[2] / best[0]:.2f}")
        results["convert"] = {str(c): runs[c] for c in configs}
        if not a.workdir:
            shutil.rmtree(work, ignore_errors=True)
    if a.overhead_tasks:
        ns = [int(x) for x in a.overhead_tasks.split(",")]
        rows = run_child(OVERHEAD_CHILD, {"workers": a.overhead_workers, "tasks": ns})
        print(f"\nmetadata-only tasks on a LocalCluster of {a.overhead_workers} single-threaded workers:")
        print("| tasks | wall | per task |")
        print("|---|---|---|")
        for row in rows:
            print(f"| {row['tasks']:,} | {row['wall']:.2f} s | {row['per_task_ms']:.3f} ms |")
        results["overhead"] = rows
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
