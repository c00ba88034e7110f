"""One exception hierarchy for gigapoint. Library code raises these; only the CLI exits."""

from __future__ import annotations

import os
import sys
import threading
import warnings
from contextlib import contextmanager
from contextvars import ContextVar

# warnings kept for another thread to issue (``warn``): set in gigapoint's threads (a
# progressive load's, a live Player's, a prefetch worker's)
_kept: ContextVar[list | None] = ContextVar("gigapoint_kept_warnings", default=None)
# ... and there other libraries' warnings too (``keep_warnings``; not ``warnings_kept``, a caller's own thread)
_keeps_library_warnings: ContextVar[bool] = ContextVar("gigapoint_keeps_library_warnings", default=False)
_shown_by_python = None  # Python's ``warnings._showwarnmsg``, once ``_show_or_keep`` stands in for it
_installing = threading.Lock()


def first_line(exc: BaseException) -> str:
    """An exception's message for a one-line error: its first line, or its type's name where it
    has none (a library's error on a bad file, quoted after the file's name)."""
    text = str(exc)
    return text.splitlines()[0] if text.strip() else type(exc).__name__


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` things as a message says them: '1 point', '2,000 points' (``plural``: where adding
    's' is wrong, 'batches'); the count as ``count_text`` says it."""
    return f"{count_text(n)} {noun if n == 1 else plural or noun + 's'}"


def count_text(n) -> str:
    """A count as a message says it: exact with thousands' commas ('2,000'), or from 1e15 on in
    three significant digits ('1.18e+303'): the cells, pixels or tiles an absurd size makes (a
    cell of 1e-300) were printed in 300 digits."""
    return f"{n:,.0f}" if n < 1e15 else f"{n:.3g}"


def count_or_inf(count) -> int | float:
    """``count()``: cells, tiles, pixels or levels counted from an extent over a size (with
    ``math.floor``), or math.inf where that division overflows (a subnormal size, 5e-324:
    ``math.floor(inf)`` was an OverflowError, an internal error): more than any limit, so that the
    caller's one-line too-large refusal says it (``count_text(math.inf)``: 'inf')."""
    import math

    import numpy as np

    with np.errstate(over="ignore", invalid="ignore"):  # (numpy's extents: no 'overflow encountered' warning besides)
        try:
            return count()
        except (OverflowError, ValueError):  # (ValueError: math.floor(nan), an extent of inf - inf)
            return math.inf


def number_text(value) -> str:
    """A number as a message says it: compact and exact ('2e+12', '0', '0.25': a bound such as
    2e12 was spelled 2000000000000.0); '%g' where it reads back as the same number, else the
    float's repr; an integer in full, anything else (a string, True, None) as its repr."""
    import numbers

    if is_whole_number(value):
        return str(int(value))
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return one_line_repr(value)
    compact = f"{value:g}"
    return compact if float(compact) == value else repr(float(value))


def value_text(value) -> str:
    """A value a count or class was given as, as a message quotes it: an integer (Python's or
    numpy's) in digits (numpy's repr said np.int64(300)), anything else as its repr (2.0 stays
    visibly a float: why an integer refuses it)."""
    return str(int(value)) if is_whole_number(value) else one_line_repr(value)


#: the most characters of a value a message quotes (a clip_polygon list of 2,000 vertices made an error line of 85,000)
REPR_MAX = 80


def one_line_repr(value) -> str:
    """``repr(value)`` where it is one line, as a one-line message quotes a value (but for a
    string or path, a file's name said in full, its first ``REPR_MAX`` characters and '...' where
    longer); else what the value is: a numpy array by its shape ('a 2x3 array', 'an array of
    1,000 values'), anything else by its type ('a DataFrame'). A 2-D array given as clip=
    printed its rows over lines."""
    import os

    import numpy as np

    text = repr(value)
    if "\n" not in text:
        return text if len(text) <= REPR_MAX or isinstance(value, (str, os.PathLike)) else f"{text[: REPR_MAX - 3]}..."
    if isinstance(value, np.ndarray):  # (a long 1-D one's repr spans lines too)
        return f"an array of {counted(value.size, 'value')}" if value.ndim == 1 else f"a {'x'.join(map(str, value.shape))} array"
    return type_text(value)


def type_text(value) -> str:
    """What ``value`` is, by its type, as a message names it: 'a list', 'an int' (not 'a int')."""
    name = type(value).__name__
    return f"{'an' if name[0] in 'AEIOUaeiou' else 'a'} {name}"


def numbers_text(values, spell=number_text) -> str:
    """A value given as numbers (a clip box, a line), as the label of its errors quotes it: a
    tuple or list (a 1-D numpy array as a list) with each item by ``spell`` ('clip=(1e+13, 0,
    5, 1)': its repr said 10000000000000.0 where the message said 1e+13); anything else (a
    number, a string, None) by ``spell`` alone."""
    import numpy as np

    if isinstance(values, np.ndarray) and values.ndim == 1:
        values = values.tolist()
    if not isinstance(values, (tuple, list)):
        return spell(values)
    items = ", ".join(map(spell, values))
    return f"[{items}]" if isinstance(values, list) else f"({items}{',' if len(values) == 1 else ''})"


def is_whole_number(value) -> bool:
    """Whether ``value`` is an integer (Python's or numpy's, not a bool): the test behind the
    one-line errors about counts, sizes and indices (3.5 was read as 3, True as 1)."""
    import numbers

    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_real(value) -> bool:
    """Whether ``value`` is a finite real number (Python's or numpy's, not a bool, not a string):
    the test behind the one-line errors about sizes, angles and rates ('a' was a TypeError inside)."""
    import math
    import numbers

    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def check_whole(where: str, name: str, value, lo: int | None = None, hi: int | None = None, unit: str = "") -> int:
    """``value`` as an int, or a one-line InputError (``where: name must be an integer from lo
    to hi unit, got ...``) unless it is a whole number (``is_whole_number``) in ``lo..hi``
    (either end None: open). The one check behind the API's counts and sizes (a demo's seed, a
    turntable's frames, a live cloud's chunk, a viewer's width, a neighbour count)."""
    if is_whole_number(value) and (lo is None or value >= lo) and (hi is None or value <= hi):
        return int(value)
    if lo is not None and hi is not None:
        rng = f" from {lo:,} to {hi:,}"
    elif lo is not None:
        rng = f" >= {lo:,}"
    else:
        rng = "" if hi is None else f" <= {hi:,}"
    raise InputError(f"{where}: {name} must be an integer{rng}{unit}, got {value_text(value)}")


def check_timeout(where: str, timeout) -> float | None:
    """``timeout`` (seconds; None or inf: no limit; below 0: none at all) as waits take it, else
    a one-line InputError: NaN waited forever, a string was a TypeError inside the wait."""
    import math
    import numbers

    if timeout is None or isinstance(timeout, numbers.Real) and not isinstance(timeout, bool) and not math.isnan(timeout):
        return None if timeout is None or timeout == math.inf else float(timeout)
    raise InputError(f"{where}: timeout must be a number of seconds or None, got {timeout!r}")


def check_switch(name: str, value, where: str, allow_none: bool = False) -> None:
    """A one-line InputError (``where: name must be ...``) unless ``value`` is True or False
    (numpy's too; None where ``allow_none``): a string such as "no" was taken as true, and an
    ``overwrite="no"`` replaced what the user had."""
    import numpy as np

    if value is None and allow_none or isinstance(value, (bool, np.bool_)):
        return
    raise InputError(f"{where}: {name} must be True or False{' or None' if allow_none else ''}, got {value!r}")


class GigapointError(Exception):
    """Base class of every error gigapoint raises on purpose.

    ``str(err)`` is always one line that names the file or option and the problem,
    so the CLI can print it as it is.
    """

    def _render_traceback_(self) -> list[str]:
        """What IPython/Jupyter shows for it: the one line, as the CLI does (a missing file was a
        38-line traceback through gigapoint's internals); ``%debug`` still walks the stack."""
        return [f"{type(self).__name__}: {self}"]


class InputError(GigapointError):
    """A file or array that cannot be read: missing, truncated, corrupt, wrong format."""


class UnsupportedFormatError(InputError):
    """No reader recognises the file."""


class EmptyCloudError(InputError):
    """The input holds no valid point."""


class CameraError(GigapointError):
    """Impossible camera or image settings (zero size, NaN eye, eye == target...)."""


class SettingsError(GigapointError):
    """An invalid RenderSettings value."""


class PointIndexError(GigapointError, IndexError):
    """A point index outside a cloud (-1, what an empty pixel holds, is not one: point_info gives None)."""


class BackendUnavailableError(GigapointError):
    """A requested backend is not installed or cannot start."""


class MemoryLimitError(GigapointError):
    """Loading stopped because what was loaded reached its memory limit (what was loaded stays
    usable), or a cloud cannot be built on this machine (its memory or temporary disk)."""


class GigapointWarning(UserWarning):
    """Warnings about degenerate but valid input (skipped points, empty views)."""


# gigapoint's files and Python's own (contextlib's, threading's: between gigapoint's frames)
_NOT_THE_USERS = (os.path.dirname(os.path.abspath(__file__)) + os.sep, os.path.dirname(os.__file__) + os.sep)


def outside_stacklevel() -> int:
    """``warnings.warn``'s stacklevel, for its caller, that names the first frame outside
    gigapoint (and Python's library): the user's line (a notebook cell, a script), not
    gigapoint's own (``renderer.py:78: ... warnings.warn(f"{cloud.name}: ...")``), however deep
    the warning arose and by whichever way it was reached; the caller's caller where there is
    none (a thread of gigapoint's)."""
    frame, level = sys._getframe(2), 2
    while frame is not None and frame.f_code.co_filename.startswith(_NOT_THE_USERS):
        frame, level = frame.f_back, level + 1
    return level if frame is not None else 2


def warn(message: str, category: type[Warning] = GigapointWarning) -> None:
    """``warnings.warn`` as gigapoint warns: at the first line outside gigapoint
    (``outside_stacklevel``); but in a context that keeps its warnings (``keep_warnings``: a
    progressive load's threads; ``warnings_kept``) the warning is appended to its list instead,
    for the caller's thread to issue (KeptWarnings.issue): Python's filters, ``catch_warnings``,
    pytest.warns and ``-W error`` are process-wide and not thread-safe, so a warning issued on the
    loader's thread escaped a catch around ``wait()`` and printed at a random moment."""
    kept = _kept.get()
    if kept is None:
        warnings.warn(message, category, stacklevel=outside_stacklevel())
    else:
        kept.append((message, category))


class KeptWarnings(list):
    """(message, category) of the warnings a thread of gigapoint's kept (``keep_warnings``), in
    order, for a caller's thread to ``issue``."""

    def __init__(self) -> None:
        super().__init__()
        self._issued = 0  # of them issued
        self._issuing = threading.Lock()

    def issue(self) -> None:
        """Issue those not issued yet, each once and in order, in this (the caller's) thread, where
        its filters and catches apply, at the caller's line (``warn``); in a context that keeps
        warnings itself (a load's thread taking a prefetch's items), into its list."""
        with self._issuing:
            new = self[self._issued :]
            self._issued += len(new)
        for message, category in new:
            warn(message, category)


def keep_warnings(kept: list) -> None:
    """From now on, in this context (a thread started with its own), ``warn`` appends to ``kept``,
    and so do the warnings other libraries issue through Python's ``warnings`` (``_show_or_keep``)."""
    _route_library_warnings()
    _kept.set(kept)
    _keeps_library_warnings.set(True)


def _route_library_warnings() -> None:
    """``_show_or_keep`` in place of ``warnings._showwarnmsg``, once for the process. Not the public
    ``warnings.showwarning``: ``catch_warnings`` (pytest.warns) swaps that for its block, so a
    caller's catch took a thread's warnings again; ``_showwarnmsg``, which calls it, it leaves."""
    global _shown_by_python
    with _installing:
        if _shown_by_python is None:
            _shown_by_python, warnings._showwarnmsg = warnings._showwarnmsg, _show_or_keep


def _show_or_keep(msg: warnings.WarningMessage) -> None:
    """Shows a warning that Python's filters let through (``warnings._showwarnmsg``), as Python
    would; but on a thread of gigapoint's that keeps its warnings (``keep_warnings``) a library's
    (numpy's "overflow encountered in cast" packing an attribute on a progressive load's thread)
    is kept as gigapoint's own are, each distinct one once, for the caller's thread to issue: shown
    from the thread it printed amid progress bars, as often as it came, and a ``pytest.warns`` or
    ``catch_warnings`` around ``wait()`` missed it. Which thread keeps is this context's (a
    thread's own), so threads do not race as with ``catch_warnings``, which swaps globals."""
    kept = _kept.get()
    if kept is None or not _keeps_library_warnings.get():
        _shown_by_python(msg)
        return
    warning = (str(msg.message), msg.category)
    if warning not in kept:
        kept.append(warning)


@contextmanager
def warnings_kept(kept: list | None = None):
    """``warn``'s warnings in the block appended to ``kept`` (a new list by default), which it
    gives, not issued (for the caller to sort: the viewer drops "no point is in view", normal
    while flying around; or to issue in another thread: a frame pushed into a live cloud)."""
    kept = [] if kept is None else kept
    token = _kept.set(kept)
    try:
        yield kept
    finally:
        _kept.reset(token)
