"""The gigapoint command line: thin wrappers that parse arguments and call the library.

Every command module registers itself on ``app`` (app.py); ``main`` turns GigapointError (and
the few OS errors a user can cause) into one line on stderr and a non-zero exit, and click's
usage errors (exit 2) into one line too.
"""

from __future__ import annotations

import atexit
import importlib
import os
import signal
import sys
import threading
import warnings

from ..errors import GigapointError, GigapointWarning
from .app import app

__all__ = ["app", "exit_without_teardown", "main", "run"]


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"warning: {message}", file=sys.stderr)


class _Terminated(SystemExit):
    """SIGTERM (``kill``, a batch system's stop) raised as an exception: it unwinds as Ctrl+C
    does, so an atomic write removes its temporary file (a killed ``render -o x.mp4`` left a
    playable half video, hidden beside it) and a conversion's lock and state are left clean."""


def _terminate(signum, frame):
    raise _Terminated(128 + signum)


def _compile_watch():
    from .compiling import watching
    from .progress import err_console

    return watching(err_console())


def _skip_blas_check() -> None:
    from ..core.threads import skip_blas_check

    skip_blas_check()


#: hints the library words for Python, and the option each is on the command line
PYTHON_HINTS = {
    "overwrite=True": "--overwrite",
    "gp.convert(..., from_crs=...)": "--from-crs",  # (io/reproject.py: a file naming no CRS)
    "gp.tile(..., from_crs=...)": "--from-crs",
    "read with recursive=True": "read with --recursive",  # (lod/convert/tiles.py: tiles inside a folder read)
    "give client its scheduler's address": "give its scheduler's address with --dask",  # (lod/convert/distributed.py: too many workers)
    "port must be in 0..65535": "--port must be in 0..65535",  # (viewer/server.py: gp.Viewer's port, view's --port)
    "host must be an address or a host name": "--host must be an address or a host name",
    "write format='copc' into": "write --format copc into",  # (lod/convert/converter.py: an octree folder named as a point file)
}


def said_as_options(message: str) -> str:
    """A library error's ``message`` with its hints for Python (PYTHON_HINTS) told as the options."""
    for python, option in PYTHON_HINTS.items():
        message = message.replace(python, option)
    return message


def _click_errors():
    """The module of click's exceptions typer raises: click's own (older typer) or typer's copy
    of it (typer 0.29); typer exports BadParameter alone of them."""
    import typer

    return importlib.import_module(typer.BadParameter.__module__)


def _param_name(param) -> str:
    """How the command line spells a parameter: an option's long name, an argument's in capitals (as --help shows them)."""
    return max(param.opts, key=len) if param.param_type_name == "option" else (param.name or "").upper()


def _bad_value(exc) -> str:
    """Why a value was refused. typer converts values with pydantic and words its first error
    ('Input should be a valid integer, unable to parse string as an integer'): that is said of
    the value itself, as click did ("'abc' is not a valid integer")."""
    from pydantic import ValidationError

    if not isinstance(exc.__cause__, ValidationError):
        return exc.message
    error = exc.__cause__.errors()[0]
    wanted = error["msg"].removeprefix("Input should be ")
    if wanted == error["msg"]:  # "Value error, 'z' is not one of 'p', 'q'."
        return error["msg"].removeprefix("Value error, ")
    return f"{error['input']!r} is not {wanted.split(', unable to parse')[0]}"


def _close_options(unknown: str, ctx) -> list[str]:
    """The command's long options ``unknown`` (an option it lacks) is likely a typo of, best
    first, at most three: click suggested any with difflib's ratio over 0.6 ('--bogus': 'Possible
    options: --gsd'); here 0.75 ('--outptu': --output, '--ips': --ipd) or options it begins
    ('--point': --point-size, --point-shape, --point-budget)."""
    import difflib

    shown = [param for param in ctx.command.get_params(ctx) if param.param_type_name == "option" and not param.hidden]
    options = {opt for param in shown for opt in (*param.opts, *param.secondary_opts) if opt.startswith("--")}
    ratio = {opt: difflib.SequenceMatcher(None, unknown, opt).ratio() for opt in options}
    close = [opt for opt in options if ratio[opt] >= 0.75 or len(unknown) >= 5 and opt.startswith(unknown)]
    # ties (--ips: --ipd and --fps) put the option sharing more of its start first
    return sorted(close, key=lambda opt: (-ratio[opt], -len(os.path.commonprefix([unknown, opt])), opt))[:3]


def _did_you_mean(exc) -> str:
    """'; did you mean --output?' after an unknown long option where one is close (``_close_options``), else ''."""
    close = _close_options(exc.option_name, exc.ctx) if exc.ctx is not None and exc.option_name.startswith("--") else []
    if not close:
        return ""
    return f"; did you mean {close[0] if len(close) == 1 else ', '.join(close[:-1]) + ' or ' + close[-1]}?"


def usage_line(exc, argv: list[str]) -> str:
    """A usage error (an unknown option, a value of the wrong type, a missing option or argument)
    in one line naming the command and the option: click printed the usage, a hint and then the
    error (four lines). ``argv`` names the command where click's error has no context
    ("option '--size' requires an argument")."""
    from .app import COMMAND_MODULES, command_name

    errors = _click_errors()
    name = command_name(argv)
    command = exc.ctx.command_path if exc.ctx is not None else "gigapoint" + (f" {name}" if name in COMMAND_MODULES else "")
    param = exc.param if isinstance(exc, errors.BadParameter) else None
    if param is None:  # 'No such option: --bogus', 'Missing argument ...' without its parameter
        # (click's suggestions for an unknown option, 'Possible options: --gsd' for --bogus, replaced by close ones)
        problem = exc.message + _did_you_mean(exc) if isinstance(exc, errors.NoSuchOption) else exc.format_message()
        problem = problem[:1].lower() + problem[1:]
    elif isinstance(exc, errors.MissingParameter):
        problem = f"missing {param.param_type_name} {_param_name(param)}"
    else:
        problem = f"{_param_name(param)}: {_bad_value(exc)}"
    return f"error: {command}: {problem.rstrip('.')} (see {command} --help)"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gigapoint`` script."""
    from ..core import hooks
    from .app import register_commands

    args = sys.argv[1:] if argv is None else argv
    register_commands(args)  # the command's module alone (every one's for --help)
    # no command's kernel uses a BLAS: scipy.linalg stays unimported (0.26 s); once numba is
    # imported (a command that runs no kernel, --help or info, imports none)
    hooks.on_numba_import(_skip_blas_check)

    warnings.showwarning = _show_warning
    warnings.simplefilter("default", GigapointWarning)
    main_thread = threading.current_thread() is threading.main_thread()  # (the only one that may set a handler)
    before = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        with _compile_watch():  # a spinner while numba compiles kernels (first run after an install)
            # (prog_name: usage errors and --help say 'gigapoint', run as python -m gigapoint.cli too)
            rv = app(args=argv, prog_name="gigapoint", standalone_mode=False)
        # typer turns Ctrl+C into Exit(130) and, outside standalone mode, *returns* that code
        # (commands themselves return None): before, an interrupted command exited 0 silently
        if isinstance(rv, int) and not isinstance(rv, bool) and rv != 0:
            if rv == 130:
                print("interrupted", file=sys.stderr)
            return rv
    except GigapointError as exc:
        print(f"error: {said_as_options(str(exc))}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except _Terminated as exc:
        print("terminated", file=sys.stderr)
        return exc.code
    except MemoryError:
        print("error: out of memory", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}".replace(": : ", ": "), file=sys.stderr)
        return 1
    except SystemExit as exc:
        return int(exc.code or 0) if isinstance(exc.code, int) else 1
    except Exception as exc:
        errors = _click_errors()
        if type(exc).__name__ == "Abort":
            return 130
        # a usage error stays exit 2, click's convention; NoArgsIsHelpError ('gigapoint' alone) shows the help
        if isinstance(exc, errors.UsageError) and not isinstance(exc, vars(errors).get("NoArgsIsHelpError", ())):
            print(usage_line(exc, args), file=sys.stderr)
            return int(exc.exit_code)
        if isinstance(exc, errors.ClickException):
            exc.show()
            return int(exc.exit_code)
        if os.environ.get("GIGAPOINT_DEBUG"):
            raise
        print(f"internal error: {type(exc).__name__}: {exc} (set GIGAPOINT_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2
    finally:
        if main_thread:  # (main() called from Python, a test: its own handler back)
            signal.signal(signal.SIGTERM, signal.SIG_DFL if before is None else before)
    return 0


def run() -> None:
    """The ``gigapoint`` console script: ``main()``, then exit without the interpreter's teardown.

    Freeing numba's and LLVM's objects at exit took 0.2-0.3 s, a sixth of the first render of a
    1 M point file (benchmarks/bench_cli.py). Everything a command owns is closed by the time
    ``main`` returns; atexit handlers still run, and a command that left a thread running
    exits the normal way, which waits for it."""
    exit_without_teardown(main())


def exit_without_teardown(code: int) -> None:
    """``run``'s exit (also a benchmark's child process that times a command as the CLI runs it):
    atexit handlers run and output is flushed, then the process ends with ``code``, numba's and
    LLVM's objects left to the OS (the interpreter's garbage collections at teardown). A thread
    still running makes it the normal exit, which waits for it."""
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        sys.exit(code)
    atexit._run_exitfuncs()  # then clears them
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said
        pass
    os._exit(code)


if __name__ == "__main__":
    run()
