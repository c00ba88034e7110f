"""The typer application every command module registers on.

typer >= 0.27 renders help itself: it shows every option's type, a flag's too (``--stats
<bool>``, ``--help <bool>``: a flag takes no value), and writes a required argument as
``{inputs}...`` on the usage line. Our commands are ``Command``s (``App.command`` gives them
that class), which show a flag without a type and an argument as ``INPUTS...``.

Path parameters pass ``readable=False``: typer's own check answered an unreadable file with a
three-line usage error (exit 2); the command's reader says ``FILE: permission denied`` in one line.
"""

from __future__ import annotations

import os

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption


def _untyped_flags(params: list) -> list:
    for p in params:
        if isinstance(p, TyperOption) and p.is_flag and p.metavar is None:
            p.metavar = ""  # the type column shows the metavar where there is one: nothing
    return params


class Command(TyperCommand):
    """A command whose help shows flags without a type and arguments as NAME... on the usage line."""

    def get_params(self, ctx) -> list:
        return _untyped_flags(super().get_params(ctx))

    def collect_usage_pieces(self, ctx) -> list[str]:
        pieces = [self.options_metavar] if self.options_metavar else []
        for p in self.get_params(ctx):
            if isinstance(p, TyperArgument):
                name = (p.metavar or p.name or "").upper() + ("..." if p.nargs != 1 else "")
                pieces.append(name if p.required else f"[{name}]")
            else:
                pieces.extend(p.get_usage_pieces(ctx))
        return pieces


class Group(TyperGroup):
    """The command group (``gigapoint --help``): its flags without a type too."""

    def get_params(self, ctx) -> list:
        return _untyped_flags(super().get_params(ctx))


class App(typer.Typer):
    """``typer.Typer`` whose commands are ``Command``s unless they ask for another class."""

    def command(self, *args, cls=None, **kwargs):
        return super().command(*args, cls=cls or Command, **kwargs)


app = App(
    name="gigapoint",
    help="Render massive point clouds fast: LAS/LAZ/PLY/E57/XYZ/NPY to images, octrees and a browser viewer.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    cls=Group,
)


def _print_version(given: bool) -> None:
    if given:
        from .. import __version__

        typer.echo(f"gigapoint {__version__}")
        raise typer.Exit()


@app.callback()
def _options(
    version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version, help="Show gigapoint's version and exit."),
) -> None:
    """The options of ``gigapoint`` itself (``--version``: a bug report's first line; it was 'No such option')."""


def prefer_passive_wait() -> None:
    """For the viewer's process, before any kernel runs: numba's OpenMP threads sleep at their
    barriers instead of spinning (``OMP_WAIT_POLICY=passive``) unless the user chose otherwise.
    A viewer's frames share the cores with a loader or a sensor's producer; spinning threads
    then wait for a descheduled peer. Measured on the 2-core AMD machine, 30 frames/s streamed
    into 100 kept frames: 29.2 frames drawn/s and 64/96 ms latency passive against 27.4 and
    71/103 ms spinning (docs/benchmarks.md). Renders and benchmarks keep numba's default (a quiet
    host draws ~5 % faster spinning)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")


#: each command's module (cli/<module>.py registers it on ``app``), in the order ``--help`` lists them
COMMAND_MODULES = {
    "bench": "bench_cmd",
    "change": "change_cmd",
    "classify": "classify_cmd",
    "compile": "compile_cmd",
    "convert": "convert_cmd",
    "info": "info_cmd",
    "render": "render_cmd",
    "demo": "render_cmd",
    "section": "section_cmd",
    "tile": "tile_cmd",
    "view": "view_cmd",
    "volume": "volume_cmd",
}


def command_name(argv: list[str]) -> str | None:
    """The command ``argv`` names: its first word not an option (None: none, or a mistyped one)."""
    return next((a for a in argv if not a.startswith("-")), None)


def register_commands(argv: list[str] | None = None) -> None:
    """Import the module of the command ``argv`` names (its first word not an option), so that
    it registers on ``app``; every command's where it names none (``--help``, a mistyped one:
    typer lists them, or suggests one), none for ``--version``. ``gigapoint info`` imported render's, view's, bench's...
    modules too, ~0.1-0.2 s of its start-up. ``argv`` None: every command's (cli/commands.py)."""
    import importlib

    name = command_name(argv) if argv is not None else None
    if name is None and argv is not None and "--version" in argv and "--help" not in argv:
        return  # (an eager option: the version printed, no command looked at)
    for module in [COMMAND_MODULES[name]] if name in COMMAND_MODULES else dict.fromkeys(COMMAND_MODULES.values()):
        importlib.import_module(f"{__package__}.{module}")
