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
