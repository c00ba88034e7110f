"""A live cloud on the wgpu backend: frames replaced between draws, chunks reused, every frame the CPU's."""

from __future__ import annotations

import numpy as np
import pytest
from wgpu_support import cpu, gpu, wgpu_or_skip  # noqa: F401 - fixtures

import gigapoint as gp
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.live import LiveCloud

pytestmark = pytest.mark.gpu
MAX_DIFF_FRACTION = 0.002  # GPUs round pixel edges their own way; lavapipe agrees exactly


def test_ring_frames_on_the_gpu_equal_the_cpu_as_chunks_are_reused(gpu, cpu):
    rng = np.random.default_rng(3)
    live = LiveCloud(keep=2)
    cam = gp.Camera.fit((np.array([-6.0, -6, -1]), np.array([12.0, 6, 1])), view="iso", width=200, height=150)
    settings = gp.RenderSettings(size_mode="fixed")
    versions = []
    for k in range(6):
        xyz = rng.uniform(-5, 5, (15_000 + 1000 * k, 3)) * [1, 1, 0.1] + [k, 0, 0]
        live.push(xyz, rng.integers(0, 255, (len(xyz), 3), dtype=np.uint8))
        with live.reading():
            draw = live.prepare(cam.view(live.bounds), settings)
            near, far = cam.clip_range(live.bounds)
            want = cpu.rasterize(draw.points, draw.selection, cam.width, cam.height, near, far)
            got = gpu.rasterize(draw.points, draw.selection, cam.width, cam.height, near, far)
        versions.append(draw.points.version)
        assert int(np.count_nonzero(got != want)) <= MAX_DIFF_FRACTION * want.size
        assert np.count_nonzero(want != EMPTY_PIXEL) > 1000
    assert len(set(versions)) == 6 and live.buffers() is draw.points  # one set of buffers rewritten in place


def test_packed_small_frames_on_the_gpu_equal_the_cpu_as_they_join_and_leave_chunks(gpu, cpu):
    """Small frames share ring chunks: each joins the open chunk (its words made anew, the
    chunk's ``batch_version`` bumped) and leaves from a chunk's front (its first moved on, no
    words written): the GPU's copies draw what the CPU draws after every push."""
    rng = np.random.default_rng(4)
    live = LiveCloud(keep=25)
    cam = gp.Camera.fit((np.array([-3.0, -3, -1]), np.array([9.0, 3, 1])), view="iso", width=160, height=120)
    settings = gp.RenderSettings(size_mode="fixed")
    for k in range(80):
        xyz = rng.uniform(-2, 2, (300, 3)) * [1, 1, 0.2] + [0.08 * k, 0, 0]
        live.push(xyz, rng.integers(0, 255, (300, 3), dtype=np.uint8))
        if k % 4 and k < 70:
            continue
        with live.reading():
            draw = live.prepare(cam.view(live.bounds), settings)
            near, far = cam.clip_range(live.bounds)
            want = cpu.rasterize(draw.points, draw.selection, cam.width, cam.height, near, far)
            got = gpu.rasterize(draw.points, draw.selection, cam.width, cam.height, near, far)
        assert int(np.count_nonzero(got != want)) <= MAX_DIFF_FRACTION * want.size, k
        assert np.count_nonzero(want != EMPTY_PIXEL) > 250  # (one frame of 300 points at first)
    ring = live.buffers_.batches[: live.buffers_.n_ring]
    assert int((ring["count"] > 0).sum()) <= 3  # 25 frames of 300 points: one or two chunks (and one opening)
