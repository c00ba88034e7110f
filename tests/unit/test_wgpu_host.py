"""Host side of the wgpu backend, no GPU needed: generated WGSL structs, the shader loader,
page planning, and the error when wgpu is missing."""

from __future__ import annotations

import re
import sys
from importlib import resources

import numpy as np
import pytest

from gigapoint.backends.wgpu import WgpuBackend
from gigapoint.backends.wgpu.layout import GPU_BATCH_DTYPE, PARAMS_DTYPE, STRUCTS, wgsl_struct
from gigapoint.backends.wgpu.memory import plan_pages
from gigapoint.backends.wgpu.shaders import PASSES, shader_source
from gigapoint.core.layout import BATCH_DTYPE
from gigapoint.errors import BackendUnavailableError, GigapointError


def _fields(text: str) -> list[tuple[str, str]]:
    return re.findall(r"^\s+(\w+): (.+),$", text, re.MULTILINE)


def test_batch_record_struct_follows_the_dtype():
    text = wgsl_struct("BatchRecord", GPU_BATCH_DTYPE)
    assert _fields(text) == [
        ("rows", "array<vec4<f32>, 4>"), ("first", "u32"), ("local_first", "u32"), ("count", "u32"), ("bits", "u32"),
        ("ext_first", "u32"), ("code", "u32"), ("_pad0", "u32"), ("_pad1", "u32"),
    ]  # fmt: skip
    # row-major: rows[i] is row i of the 4x4 matrix, as the CPU kernel indexes m[i, j]
    rec = np.zeros(1, GPU_BATCH_DTYPE)
    rec["rows"][0] = np.arange(16, dtype=np.float32).reshape(4, 4)
    assert rec.view(np.float32)[:16].tolist() == list(range(16))
    assert GPU_BATCH_DTYPE.itemsize == 96


def test_params_struct_is_a_multiple_of_16_bytes():
    text = wgsl_struct("Params", PARAMS_DTYPE)
    names = [n for n, _ in _fields(text)]
    assert names == list(PARAMS_DTYPE.names)
    assert PARAMS_DTYPE.itemsize % 16 == 0
    assert dict(_fields(text))["near"] == "f32"


@pytest.mark.parametrize(
    "dtype, problem",
    [
        (np.dtype([("a", "<u4"), ("v", "<f4", (4,))]), "byte 16"),  # vec4 needs 16-byte alignment
        (np.dtype([("a", "<f8")]), "no WGSL equivalent"),  # no portable 64-bit scalar
        (np.dtype([("v", "<f4", (4,)), ("a", "<u4")]), "size"),  # struct rounds up to 32 bytes
    ],
)
def test_layouts_wgsl_cannot_match_are_refused(dtype, problem):
    with pytest.raises(TypeError, match=problem):
        wgsl_struct("Bad", dtype)


def test_shaders_get_generated_structs_and_shared_code_once():
    for name in PASSES:
        src = shader_source(name)
        for struct in STRUCTS:
            assert src.count(f"struct {struct} {{") == 1, (name, struct)
        assert not re.search(r"^//! include", src, re.MULTILINE), name
    raster = shader_source("raster64")
    assert raster.count("fn grid_coords(") == 1 and raster.count("fn project(") == 1
    assert "fn grid_coords(" not in shader_source("resolve")


def test_no_shader_file_types_a_struct_by_hand():
    folder = resources.files("gigapoint.backends.wgpu").joinpath("shaders")
    files = [f for f in folder.iterdir() if f.name.endswith(".wgsl")]
    assert {f.name[:-5] for f in files} >= set(PASSES)
    for f in files:
        assert not re.search(r"^\s*struct\s", f.read_text(), re.MULTILINE), f.name


def test_unknown_pass_is_named():
    with pytest.raises(KeyError, match="raster128"):
        shader_source("raster128")


def _batches(counts, firsts=None):
    b = np.zeros(len(counts), BATCH_DTYPE)
    b["count"] = counts
    b["first"] = np.concatenate([[0], np.cumsum(counts)[:-1]]) if firsts is None else firsts
    return b


def test_pages_hold_whole_batches_up_to_the_limit():
    counts = [4, 4, 3, 5, 1, 8, 2]
    starts, stops, page_of = plan_pages(_batches(counts), 10)
    assert starts.tolist() == [0, 8, 17] and stops.tolist() == [8, 17, 27]  # 4+4 | 3+5+1 | 8+2
    assert page_of.tolist() == [0, 0, 1, 1, 1, 2, 2]


def test_pages_follow_point_order_not_batch_order():
    b = _batches([5, 5, 5], firsts=[10, 0, 5])  # LOD nodes need not be stored in order
    starts, stops, page_of = plan_pages(b, 10)
    assert starts.tolist() == [0, 10] and stops.tolist() == [10, 15]
    assert page_of.tolist() == [1, 0, 0]


def test_one_page_when_everything_fits():
    starts, stops, page_of = plan_pages(_batches([10_240] * 5), 1 << 25)
    assert starts.tolist() == [0] and stops.tolist() == [51_200] and set(page_of.tolist()) == {0}


def test_a_batch_over_the_page_size_is_named():
    with pytest.raises(GigapointError, match="batch 1 holds 12 points"):
        plan_pages(_batches([3, 12]), 10)


@pytest.mark.filterwarnings("ignore")
def test_missing_wgpu_is_backend_unavailable(monkeypatch):
    monkeypatch.setitem(sys.modules, "wgpu", None)  # import wgpu -> ImportError
    with pytest.raises(BackendUnavailableError, match=r"pip install 'gigapoint\[gpu\]'"):
        WgpuBackend()


def test_stale_ranges_are_the_rewritten_batches_merged_and_never_empty():
    """What a re-upload sends: the batches written after a version, touching ones merged; a
    batch emptied since (a progressive leaf that split) sends nothing (wgpu refuses a write of
    zero bytes)."""
    from types import SimpleNamespace

    from gigapoint.backends.wgpu.memory import stale_ranges

    b = np.zeros(5, BATCH_DTYPE)
    b["first"] = [0, 100, 200, 300, 400]
    b["count"] = [100, 100, 0, 50, 100]
    cloud = SimpleNamespace(batches=b, batch_version=np.array([1, 5, 5, 5, 5]))
    assert stale_ranges(cloud, 2, 0, 500) == [(100, 200), (300, 350), (400, 500)]
    assert stale_ranges(cloud, 2, 150, 450) == [(150, 200), (300, 350), (400, 450)]
    assert stale_ranges(cloud, 5, 0, 500) == []
    assert stale_ranges(SimpleNamespace(batches=b, batch_version=None), 0, 10, 20) == [(10, 20)]
    # ranges at most ``gap`` rows apart go as one (fewer writes; the rows between are current)
    assert stale_ranges(cloud, 2, 0, 500, gap=99) == [(100, 200), (300, 500)]
    assert stale_ranges(cloud, 2, 0, 500, gap=100) == [(100, 500)]
    assert stale_ranges(cloud, 2, 150, 450, gap=100) == [(150, 450)]


@pytest.mark.parametrize(("value", "off"), [("1", True), ("yes", True), ("0", False), ("", False)])
def test_no_gpu_switch_reads_its_value(monkeypatch, value, off):
    from gigapoint.backends.wgpu import backend

    monkeypatch.setattr(backend.glob, "glob", lambda pattern: ["/dev/dri/renderD128"])  # a device node, on any host
    monkeypatch.setattr(backend.sys, "platform", "linux")
    monkeypatch.setenv("GIGAPOINT_NO_GPU", value)
    assert backend.gpu_device_present() is (not off)
