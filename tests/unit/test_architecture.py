"""The seams between packages (docs/architecture.md): contracts every implementation keeps.

The import layering itself is checked by import-linter (``lint-imports``, pyproject.toml),
which scripts/test.sh runs before the tests; here: that those contracts are really checked,
and what a linter of imports cannot see.
"""

from __future__ import annotations

import ast
import inspect
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.backends.numba_cpu import NumbaCpuBackend
from gigapoint.backends.numba_cpu.passes import CpuPasses
from gigapoint.backends.wgpu.backend import WgpuBackend
from gigapoint.backends.wgpu.passes import GpuPasses
from gigapoint.core.renderable import PointBuffers, Renderable
from gigapoint.render.backend import Backend, Passes

SRC = Path(gp.__file__).parent
ROOT = SRC.parents[1]


def _protocol_methods(proto) -> list[str]:
    return [n for n, v in vars(proto).items() if callable(v) and not n.startswith("_")]


def test_the_import_contracts_hold():
    """lint-imports (layers, render never importing a backend, backends never importing the
    renderer's passes, no import cycle between files) passes on this tree."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("import-linter is not installed (pip install 'gigapoint[test]')")
    proc = subprocess.run([exe, "--no-cache"], check=False, cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert "0 broken" in proc.stdout


@pytest.mark.parametrize("impl", [CpuPasses, GpuPasses])
def test_both_backends_implement_every_pass(impl):
    """Every Passes method exists on the CPU and the GPU, with the protocol's parameters first."""
    for name in _protocol_methods(Passes):
        want = list(inspect.signature(getattr(Passes, name)).parameters)[1:]
        got = list(inspect.signature(getattr(impl, name)).parameters)
        if got and got[0] == "self":
            got = got[1:]
        assert got[: len(want)] == want, f"{impl.__name__}.{name}{got} vs Passes.{name}{want}"


@pytest.mark.parametrize("impl", [NumbaCpuBackend, WgpuBackend])
def test_both_backends_implement_the_backend_contract(impl):
    for name in _protocol_methods(Backend):
        assert callable(getattr(impl, name, None)), f"{impl.__name__} has no {name}"
    assert isinstance(impl.is_available(), bool)


def test_every_cloud_kind_is_renderable(tmp_path):
    from gigapoint.lod import convert, open_octree

    cloud = gp.demo(30_000)
    convert([cloud_chunk(cloud)], tmp_path / "oct", max_leaf=5_000)
    octree = open_octree(tmp_path / "oct")
    for c in (cloud, octree):
        assert isinstance(c, Renderable)
        cam = gp.Camera.fit(c.bounds, width=64, height=48)
        draw = c.prepare(cam.view(c.bounds), gp.RenderSettings())
        assert isinstance(draw.points, PointBuffers)
        assert len(draw.selection.ids) > 0 and draw.n_batches == len(c.batches)
    with pytest.raises(gp.GigapointError, match="cannot draw a ndarray"):
        gp.render(np.zeros((3, 3)), gp.Camera.fit(cloud.bounds))


def cloud_chunk(cloud):
    return gp.PointChunk(cloud.positions(), cloud.rgba)


def _calls(tree) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)]


def test_no_capability_probes_and_no_state_on_foreign_objects():
    """Nothing asks a cloud, its buffers, a backend or the settings what it can do by getattr /
    hasattr, and nothing sticks attributes onto objects of another class (object.__setattr__
    is for a frozen dataclass's own fields)."""
    probed = {"cloud", "points", "buffers", "backend", "arena", "settings", "frame", "last", "draw", "lod_cloud"}
    found = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for call in _calls(tree):
            f = call.func
            # hasattr(x, "name") / getattr(x, "name"[, default]); getattr(x, field_name) reads a known field
            if isinstance(f, ast.Name) and f.id in ("getattr", "hasattr") and len(call.args) >= 2:
                target, attr = call.args[0], call.args[1]
                named = isinstance(attr, ast.Constant) and isinstance(attr.value, str)
                if isinstance(target, ast.Name) and target.id in probed and (named or len(call.args) == 3 or f.id == "hasattr"):
                    found.append(f"{path.relative_to(SRC)}:{call.lineno} {f.id}({target.id}, ...)")
            if isinstance(f, ast.Attribute) and f.attr == "__setattr__" and isinstance(f.value, ast.Name) and f.value.id == "object":
                target = call.args[0] if call.args else None
                if not (isinstance(target, ast.Name) and target.id == "self"):
                    found.append(f"{path.relative_to(SRC)}:{call.lineno} object.__setattr__ on {ast.unparse(target) if target else '?'}")
    assert not found, "\n".join(found)


def test_gigapoint_warns_through_errors_warn():
    """A warning goes through ``errors.warn``: on a progressive load's threads (the readers, the
    core, the octree) it is kept for the caller's thread (``wait`` issues it; ``warnings.warn``
    issued it on the loader's, past the caller's filters and catches), and anywhere it names the
    user's line, not gigapoint's. Nor does gigapoint hide warnings with ``warnings.catch_warnings``:
    it swaps the process's filters (a caller's, on another thread, meanwhile); ``warnings_kept``
    keeps gigapoint's own in the block's context."""
    found = []
    for path in sorted(p for p in SRC.rglob("*.py") if p != SRC / "errors.py"):
        for call in _calls(ast.parse(path.read_text(encoding="utf-8"))):
            if ast.unparse(call.func) in ("warnings.warn", "warnings.catch_warnings"):
                found.append(f"{path.relative_to(SRC)}:{call.lineno}")
    assert not found, "\n".join(found)
