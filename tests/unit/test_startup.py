"""Start-up: what ``import gigapoint`` and the CLI's commands that run no kernel import
(core/hooks.py). ``import gigapoint`` imported numba and every kernel module (~0.4-1 s), so
``gigapoint --help`` and ``info`` of a LAS header took ~1.3 s where ``pdal info`` takes 0.15."""

from __future__ import annotations

import json
import subprocess
import sys

# runs a CLI command (as the console script does, main(argv)) or some code, then prints what
# it imported: numba's modules, gigapoint's, and the command's exit code
_RUN = """
import json, sys
argv = json.loads(sys.argv[1])
if argv and argv[0] == "-c":
    exec(argv[1])
    rc = 0
else:
    from gigapoint.cli import main
    rc = main(argv)
mods = sorted(sys.modules)
print(json.dumps({"rc": rc, "numba": [m for m in mods if m.split(".")[0] in ("numba", "llvmlite")], "gigapoint": [m for m in mods if m.startswith("gigapoint")], "numpy": "numpy" in mods}))
"""


def _imports(*argv: str) -> tuple[dict, str]:
    run = subprocess.run([sys.executable, "-c", _RUN, json.dumps(argv)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    *out, last = run.stdout.strip().splitlines()
    return json.loads(last), "\n".join(out)


def test_help_version_and_info_of_a_las_file_import_no_numba(autzen_path):
    """A command that runs no kernel imports neither numba nor llvmlite, nor the kernel modules."""
    for argv in (["--help"], ["--version"], ["info", str(autzen_path)], ["info", "--json", str(autzen_path)]):
        got, out = _imports(*argv)
        assert got["rc"] == 0, (argv, out)
        assert got["numba"] == [], argv
        assert not {"gigapoint.core.cloud", "gigapoint.io.las_kernels", "gigapoint.lod.store", "gigapoint.render.renderer"} & set(got["gigapoint"]), argv
    got, out = _imports("--version")
    assert out == "gigapoint 0.1.0"
    assert not got["numpy"] and not [m for m in got["gigapoint"] if m.endswith("_cmd")]  # no command's module
    got, out = _imports("info", str(autzen_path))
    assert "points:      110,000" in out and "LAZ 1.2, point format 3" in out  # the header, read by laspy alone
    assert "bounds min:  636001.76, 848935.20, 406.26 (header)" in out


def test_import_gigapoint_imports_no_numba_and_its_api_loads_on_use():
    """``import gigapoint`` imports no kernel; the public names are there when used (PEP 562),
    ``gp.render`` stays the function and ``gp.convert`` too, whatever imported their packages."""
    got, _ = _imports("-c", "import gigapoint")
    assert got["numba"] == [] and not got["numpy"]
    code = (
        "import sys, gigapoint as gp, gigapoint.render.renderer, gigapoint.lod.convert.tiles\n"
        "from gigapoint.lod import convert\n"
        "assert gp.render is sys.modules['gigapoint.render.renderer'].render\n"
        "assert gp.convert is convert and convert.__module__ == 'gigapoint.lod.convert.converter'\n"
        "assert gp.PointCloud.__module__ == 'gigapoint.core.cloud' and gp.Camera.__name__ == 'Camera'\n"
    )
    got, _ = _imports("-c", code)
    assert "numba" in got["numba"]


def test_numba_is_set_up_when_imported_after_gigapoint():
    """numba's set-up that ``import gigapoint`` did (its threading layer first in gigapoint's
    order, kernels compiled in memory where no cache is writable) is done as numba is imported."""
    code = (
        "import gigapoint, sys\n"
        "assert 'numba' not in sys.modules\n"
        "import numba\n"
        "from gigapoint.core import kernel_cache, threads\n"
        "first = 'tbb' if threads.wheel_tbb_library() else 'omp'\n"
        "assert numba.config.THREADING_LAYER_PRIORITY[0] == first, numba.config.THREADING_LAYER_PRIORITY\n"
        "assert 'installed' in kernel_cache._done\n"
    )
    got, _ = _imports("-c", code)
    assert "numba" in got["numba"]


def test_the_backends_and_the_writer_are_wired_on_first_use(tmp_path):
    """render.backend's backends and PointCloud.save's writer, registered by ``import gigapoint``
    before (importing gigapoint.backends and gigapoint.io), are there at their first use."""
    out = tmp_path / "x.las"
    code = (
        "import numpy as np, sys\n"
        "from gigapoint.core.cloud import from_arrays\n"
        "from gigapoint.render.renderer import render\n"
        "assert 'gigapoint.backends' not in sys.modules and 'gigapoint.io.write' not in sys.modules\n"
        "cloud = from_arrays(np.random.default_rng(0).random((1000, 3)))\n"
        f"assert cloud.save({str(out)!r}) == 1000\n"
        "image = render(cloud, width=64, height=48)\n"
        "assert image.shape[:2] == (48, 64)\n"
    )
    got, _ = _imports("-c", code)
    assert "gigapoint.backends" in got["gigapoint"]
    assert out.stat().st_size > 1000 * 20


def test_the_compile_watch_listens_from_numbas_import_on():
    """The CLI's compile spinner (cli/compiling.py) starts before numba is imported (``info``
    imports none); a command that then imports it still hears its compilations."""
    code = (
        "import sys\n"
        "from gigapoint.cli import compiling\n"
        "with compiling.watching() as watch:\n"
        "    assert 'numba' not in sys.modules\n"
        "    from numba.core import event\n"
        "    assert len(event._registered['numba:compile']) == 1\n"
        "assert event._registered['numba:compile'] == []\n"
    )
    _imports("-c", code)


def test_a_command_line_imports_its_command_module_alone():
    """``gigapoint info`` registers info's module alone (render's, view's, bench's... took
    ~0.1-0.2 s); ``--help`` every one, as app.py's COMMAND_MODULES says where each is."""
    got, _ = _imports("info", "--help")
    assert {m for m in got["gigapoint"] if m.endswith("_cmd")} == {"gigapoint.cli.info_cmd"}
    got, out = _imports("--help")
    assert {m for m in got["gigapoint"] if m.endswith("_cmd")} == {"gigapoint.cli." + m for m in ("bench_cmd", "change_cmd", "classify_cmd", "compile_cmd", "convert_cmd", "info_cmd", "render_cmd", "section_cmd", "tile_cmd", "view_cmd", "volume_cmd")}
    code = (
        "import typer\n"
        "from gigapoint.cli import app, commands\n"
        "from gigapoint.cli.app import COMMAND_MODULES\n"
        "registered = {c.name or c.callback.__name__: c.callback.__module__.rsplit('.', 1)[-1] for c in app.registered_commands}\n"
        "assert registered == COMMAND_MODULES, registered\n"
        "assert list(typer.main.get_command(app).commands) == list(COMMAND_MODULES)\n"
    )
    _imports("-c", code)
