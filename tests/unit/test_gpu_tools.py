"""The scripts a session lent a GPU runs (benchmarks/gpu_device.sh) work, here on lavapipe: a
lease is 15 minutes, too short to find a broken script there."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from wgpu_support import wgpu_or_skip

pytestmark = [pytest.mark.gpu, pytest.mark.slow]

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _run(script: str, *args: str) -> str:
    wgpu_or_skip()
    env = dict(os.environ, COLUMNS="200")
    out = subprocess.run([sys.executable, str(BENCHMARKS / script), *args], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_gpu_exactness_compares_every_frame_with_products_kept_and_fusable():
    """Seven frames (five small, two 1920x1080) with each shader text; lavapipe fuses nothing,
    so the wgpu visibility buffer equals the CPU's in every one (on NVIDIA the fusable one does not)."""
    lines = [line for line in _run("gpu_exactness.py", "--points", "20k", "60k").splitlines() if " products " in line]
    assert len(lines) == 14, lines
    assert sum(" products kept " in line for line in lines) == 7
    for line in lines:
        assert line.split(" products ")[1].split()[1:3] == ["0", "px"], line


def test_bench_wgpu_draws_each_view_with_both_atomics_paths_as_the_cpu_does():
    out = _run("bench_wgpu.py", "--points", "60k", "--views", "overview", "closeup", "--repeats", "1", "--fallback", "--gpu-memory", "1G")
    assert "overview: rasterize 60,000 of 60,000 points" in out and "closeup: rasterize" in out, out
    assert out.count("identical") == 4, out  # the 64-bit and the two-pass path, two views, each equal to the CPU's image


def test_gpu_early_depth_draws_every_variant_as_the_shipped_pass_does():
    """Each early-depth test, loop and batch order (and the 32-bit path) on lavapipe: the images
    equal the shipped pass's, in both views."""
    out = _run("gpu_early_depth.py", "--points", "60k", "--width", "320", "--height", "240", "--repeats", "1", "--fallback", "--front-to-back")
    assert "overview: 60,000 of 60,000 points" in out and "closeup:" in out, out
    assert out.count("identical") == 2 * (4 * 2 * 2 + 2), out  # per view: 4 tests x 2 loops x 2 orders, the 32-bit path's 2
    assert "px differ" not in out, out


def test_bench_gpu_uploads_sends_fewer_writes_with_changed_chunks_merged():
    out = _run("bench_gpu_uploads.py", "--points", "600k", "--width", "320", "--height", "240", "--rounds", "1")
    merged, single = (line for line in out.splitlines() if "changed chunks merged across gaps up to" in line)
    assert "up to 32 KiB" in merged and "up to 0 KiB" in single, out
    writes = [float(line.split(" writes ")[0].rsplit(" ", 1)[1]) for line in (merged, single)]
    assert writes[0] < writes[1], out


def test_a_bad_argument_is_argparses_one_line_error_naming_the_option():
    """(It was status 1 after wgpu was imported; bench.parse_counts now says it as argparse's
    error, status 2, before any work: test_bench_scripts checks every script the same way.)"""
    out = subprocess.run([sys.executable, str(BENCHMARKS / "bench_gpu_uploads.py"), "--points", "lots"], capture_output=True, text=True, timeout=120)
    last = out.stderr.strip().splitlines()[-1]
    assert out.returncode == 2 and "Traceback" not in out.stderr and last == "bench_gpu_uploads.py: error: --points: cannot read 'lots' (use e.g. 20M, 200k, 1e6 or 5000000)", out.stderr
