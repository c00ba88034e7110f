"""Viewer benchmark: frames/s and input-to-frame latency during a scripted orbit, over the real WebSocket.

    .venv/bin/python benchmarks/bench_viewer.py --points 1000000 --seconds 5
    .venv/bin/python benchmarks/bench_viewer.py --url ws://127.0.0.1:8765/ws   # a server already running

Without --url it starts ``gigapoint view --demo N --no-browser`` in a subprocess (so the client
does not share the server's GIL), waits for the first full frame (JIT warm-up excluded), then
sends orbit input at --rate messages/s for --seconds, as a mouse drag would, and finally stops
and times how long the full-resolution refinement takes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from gigapoint.viewer.protocol import unpack_frame


def percentile(values, q):
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q / 100 * len(s)))]


def run(url: str, width: int, height: int, seconds: float, rate: float, adaptive: bool = True) -> dict:
    from websockets.sync.client import connect

    sent: dict[int, float] = {}
    frames: list[tuple[float, dict]] = []
    lock = threading.Lock()
    sep = "&" if "?" in url else "?"
    with connect(f"{url}{sep}w={width}&h={height}", max_size=2**26, open_timeout=60) as ws:
        hello = json.loads(ws.recv(timeout=60))
        assert hello["type"] == "hello", hello
        ws.send(json.dumps({"type": "quality", "adaptive": adaptive}))
        ws.send(json.dumps({"type": "settings", "values": {"size_mode": "fixed"}}))  # the exact one-pixel render
        while True:  # warm-up: the first full frame (numba kernels loaded, caches warm)
            m = ws.recv(timeout=120)
            if isinstance(m, bytes) and unpack_frame(m)[0]["full"]:
                break
        stop = threading.Event()

        def reader():
            while not stop.is_set():
                try:
                    m = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                except Exception:  # noqa: BLE001 - closed
                    return
                if isinstance(m, bytes):
                    h, _ = unpack_frame(m)
                    with lock:
                        frames.append((time.perf_counter(), h))

        th = threading.Thread(target=reader, daemon=True)
        th.start()
        t0 = time.perf_counter()
        seq = 0
        period = 1.0 / rate
        while time.perf_counter() - t0 < seconds:
            seq += 1
            with lock:
                sent[seq] = time.perf_counter()
            ws.send(json.dumps({"type": "orbit", "dyaw": 0.8, "dpitch": 0.05 * ((seq // 60) % 2 * 2 - 1), "seq": seq}))
            time.sleep(max(0.0, t0 + seq * period - time.perf_counter()))
        t_stop = time.perf_counter()
        last_seq = seq
        while time.perf_counter() - t_stop < 5:  # wait for the refinement of the final state
            with lock:
                done = [f for f in frames if f[1]["seq"] == last_seq and f[1]["full"]]
            if done:
                break
            time.sleep(0.01)
        stop.set()
        th.join(2)
    with lock:
        moving = [(t, h) for t, h in frames if t <= t_stop and h["seq"] is not None]
        refine = [t for t, h in frames if h["seq"] == last_seq and h["full"]]
        latencies = [(t - sent[h["seq"]]) * 1000 for t, h in moving if h["seq"] in sent]
    span = (moving[-1][0] - moving[0][0]) if len(moving) > 1 else float("nan")
    scales = {}
    for _, h in moving:
        scales[h["scale"]] = scales.get(h["scale"], 0) + 1
    return {
        "viewport": f"{width}x{height}",
        "points": hello["cloud"]["points"],
        "inputs_sent": last_seq,
        "frames_while_moving": len(moving),
        "fps_while_moving": (len(moving) - 1) / span if len(moving) > 1 and span > 0 else 0.0,
        "latency_ms_median": statistics.median(latencies) if latencies else float("nan"),
        "latency_ms_p95": percentile(latencies, 95),
        "render_ms_median": statistics.median(h["render_ms"] for _, h in moving) if moving else float("nan"),
        "encode_ms_median": statistics.median(h["encode_ms"] for _, h in moving) if moving else float("nan"),
        "frames_by_scale": {f"1/{k}": v for k, v in sorted(scales.items())},
        "refine_after_stop_ms": (refine[0] - t_stop) * 1000 if refine else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", help="ws:// URL of a running viewer's /ws (default: start one)")
    ap.add_argument("--points", type=int, default=1_000_000, help="demo scene size when starting a server")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--rate", type=float, default=60.0, help="orbit messages per second (a mouse drag sends ~60)")
    ap.add_argument("--no-adaptive", action="store_true", help="full resolution while moving (for comparison)")
    args = ap.parse_args()
    proc = None
    url = args.url
    if url is None:
        proc = subprocess.Popen(
            [sys.executable, "-m", "gigapoint.cli", "view", "--demo", str(args.points), "--no-browser"],
            stdout=subprocess.PIPE,
            text=True,
        )
        page = proc.stdout.readline().strip()
        if not page.startswith("http"):
            proc.kill()
            print(f"server did not start: {page!r}", file=sys.stderr)
            return 1
        url = page.replace("http://", "ws://", 1).split("?")[0] + "ws"
    try:
        result = run(url, args.width, args.height, args.seconds, args.rate, adaptive=not args.no_adaptive)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(10)
    for k, v in result.items():
        print(f"{k:24s} {v:.1f}" if isinstance(v, float) else f"{k:24s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
