"""The gigapoint command line: thin wrappers that parse arguments and call the library.

Every command module registers itself on ``app`` (app.py); ``main`` turns GigapointError (and
the few OS errors a user can cause) into one line on stderr and a non-zero exit.
"""

from __future__ import annotations

import atexit
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


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gigapoint`` script."""
    from ..core import hooks
    from .app import register_commands

    register_commands(sys.argv[1:] if argv is None else argv)  # the command's module alone (every one's for --help)
    # no command's kernel uses a BLAS: scipy.linalg stays unimported (0.26 s); once numba is
    # imported (a command that runs no kernel, --help or info, imports none)
    hooks.on_numba_import(_skip_blas_check)

    warnings.showwarning = _show_warning
    warnings.simplefilter("default", GigapointWarning)
    main_thread = threading.current_thread() is threading.main_thread()  # (the only one that may set a handler)
    before = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        with _compile_watch():  # a spinner while numba compiles kernels (first run after an install)
            rv = app(args=argv, standalone_mode=False)
        # typer turns Ctrl+C into Exit(130) and, outside standalone mode, *returns* that code
        # (commands themselves return None): before, an interrupted command exited 0 silently
        if isinstance(rv, int) and not isinstance(rv, bool) and rv != 0:
            if rv == 130:
                print("interrupted", file=sys.stderr)
            return rv
    except GigapointError as exc:
        # the library words an overwrite hint for Python (overwrite=True): here it is the option
        print(f"error: {exc}".replace("overwrite=True", "--overwrite"), file=sys.stderr)
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
        # typer bundles click; its usage errors carry show() and exit_code
        if type(exc).__name__ == "Abort":
            return 130
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
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
