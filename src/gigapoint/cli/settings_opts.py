"""Command-line options generated from a settings dataclass (RenderSettings, render/settings.py).

Every field becomes one option of the command decorated with ``with_settings_options``: its
type gives the option's kind (a flag, ``--x/--no-x`` when the default is on, a choice from the
``Literal``, a number, ``'low,high'`` text for ranges, a color name), its metadata the help
text, the option name and the help panel, its default the option's default. Values are
checked by the dataclass itself, and an error names the option that set the field, in one
line (``error: --fill-holes: fill_holes must be an integer in [0, 3], got 7``).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
from contextlib import contextmanager
from typing import Annotated, Any, Literal

import typer
from rich.markup import escape

from ..errors import GigapointError, SettingsError
from ..render.settings import GROUPS, RenderSettings, SettingSpec, format_color, help_text, implied_fields, settings_fields

PANELS = {"execution": "Execution", "lod": "Precision, culling and level of detail", "appearance": "Appearance"}
_MAX_METAVAR = 30
_CTX = "_settings_ctx"  # the typer.Context parameter the generated command receives


@dataclasses.dataclass(frozen=True)
class SettingOption:
    """One generated option: the field it sets, its declaration, and what its help shows."""

    spec: SettingSpec
    decl: str  # "--edl", "--adaptive-precision/--no-adaptive-precision"
    annotation: Any  # the type typer sees (Literal choices, int, float, str, bool; | None when nullable)
    default: Any  # as typed on the command line (a color name, 'low,high')
    help: str
    panel: str
    show_choices: bool = True  # in the type column, [a|b|c]; long lists go into the help text instead

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def option(self) -> str:
        return self.spec.option

    @property
    def choices(self) -> tuple:
        return self.spec.choices


def _bounds(spec: SettingSpec) -> str:
    lo, hi = spec.min, spec.max
    if lo is not None and hi is not None:
        return f"[{lo}{'<' if spec.exclusive_min else '<='}x<={hi}]"
    if lo is not None:
        return f"[x{'>' if spec.exclusive_min else '>='}{lo}]"
    return f"[x<={hi}]" if hi is not None else ""


def _range_text(v) -> str | None:
    return None if v is None else f"{v[0]:g},{v[1]:g}"


def setting_option(spec: SettingSpec, cls: type = RenderSettings) -> SettingOption | None:
    """The option of one field of ``cls``, or None for a field of a type no option can set."""
    kind, default, nullable = spec.kind, spec.default, spec.nullable
    if kind == "other" or default is dataclasses.MISSING:
        return None
    decl = spec.option
    if kind == "bool":
        annotation = bool
        if default:
            decl = f"{decl}/--no-{decl.removeprefix('--')}"
        default = bool(default)
    elif kind == "enum":
        annotation = spec.enum or Literal[tuple(spec.choices)]  # shown as [a|b|c], completed by the shell
        default = default.value if spec.enum is not None and default is not None else default
    elif kind in ("int", "float"):
        annotation = int if kind == "int" else float
    elif kind == "color":
        annotation, default = str, (None if default is None else format_color(default))
    elif kind == "range":
        annotation, default = str, _range_text(default)
    elif kind == "classes":  # '7,18'; none hidden shows no default
        annotation, default = str, ",".join(map(str, default)) or None
    else:
        annotation = str
    if nullable or default is None:
        annotation = annotation | None
    listed = kind == "enum" and len("|".join(map(str, spec.choices))) > _MAX_METAVAR  # too long for the type column
    helped = help_text(cls, spec, lambda other: other.option)  # 'values of color_attribute' -> '--color-attribute'
    text = " ".join(filter(None, [helped, f"One of: {', '.join(map(str, spec.choices))}." if listed else "", _bounds(spec)]))
    return SettingOption(spec, decl, annotation, default, escape(text), PANELS.get(spec.group, spec.group.title()), not listed)


def settings_options(cls: type = RenderSettings) -> list[SettingOption]:
    """One option per field of the settings dataclass ``cls``: by group (GROUPS order), then in field order."""
    opts = [o for o in (setting_option(spec, cls) for spec in settings_fields(cls)) if o is not None]
    return sorted(opts, key=lambda o: GROUPS.index(o.spec.group) if o.spec.group in GROUPS else len(GROUPS))


def option_of(cls: type = RenderSettings) -> dict[str, str]:
    """Field name -> the option that sets it."""
    return {o.name: o.option for o in settings_options(cls)}


# --- parsing: lenient, so that a bad value reaches the dataclass, whose message names the option ---
def _number(text, kinds=(int, float)):
    """The number a command-line word spells; other text goes on unchanged (the dataclass rejects it, naming the option)."""
    if not isinstance(text, str):
        return text
    for kind in kinds:
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _float(text):
    return _number(text, (float,))


def _choice(choices: tuple):
    by_text = {str(c.value if isinstance(c, enum.Enum) else c): c for c in choices}

    def parse(text):
        if not isinstance(text, str):
            return text
        return by_text.get(text, _number(text))

    return parse


def _parameter(opt: SettingOption) -> inspect.Parameter:
    extra: dict = {}
    if opt.spec.kind in ("int", "float"):
        extra["parser"] = _number if opt.spec.kind == "int" else _float
    elif opt.spec.kind == "enum":
        extra["parser"] = _choice(tuple(opt.spec.enum) if opt.spec.enum else opt.spec.choices)
    info = typer.Option(opt.decl, help=opt.help, rich_help_panel=opt.panel, show_choices=opt.show_choices, **extra)
    return inspect.Parameter(opt.name, inspect.Parameter.KEYWORD_ONLY, default=opt.default, annotation=Annotated[opt.annotation, info])


def settings_parameters(cls: type = RenderSettings) -> list[inspect.Parameter]:
    """The generated options as keyword-only parameters (``Annotated[type, typer.Option(...)]``) named like the fields."""
    return [_parameter(o) for o in settings_options(cls)]


def _pair(option: str, text):
    if text is None or not isinstance(text, str):
        return text
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise SettingsError(f"{option}: expected 'low,high', got {text!r}") from None
    return (lo, hi)


def settings_from_options(cls: type, values: dict, given: frozenset | set = frozenset()):
    """``cls(**fields)`` from the values of its generated options (``given``: the fields whose
    options were typed on the command line; they set the fields their metadata ``implies``).
    A bad value is a one-line SettingsError that names its option.
    """
    opts = {o.name: o for o in settings_options(cls)}
    blame = {name: o.option for name, o in opts.items()}
    kwargs = {}
    for name, value in values.items():
        if name not in opts:
            raise SettingsError(f"unknown render setting(s): {name}")
        kind = opts[name].spec.kind
        if kind == "classes" and value is None:
            continue  # not given: the field's default (none hidden)
        kwargs[name] = _pair(blame[name], value) if kind == "range" else value
    for target, (value, source) in implied_fields(cls, given).items():  # e.g. --point-world-size: attenuated points, 16 px at most
        if target in opts:
            kwargs[target] = value
            blame[target] = blame[source]
    try:
        settings = cls(**kwargs)
    except SettingsError as exc:
        raise named_option(exc, blame) from None
    check_needs(settings, given)
    return settings


def _or(values) -> str:
    words = [str(v) for v in values]
    return " or ".join(filter(None, [", ".join(words[:-1]), words[-1]]))


def check_needs(settings, given) -> None:
    """A one-line SettingsError for an option given on the command line (``given``: field names)
    that ``settings`` would not read: its field's ``needs`` (another field's values) not met
    (``--ipd`` without ``--stereo``, ``--colormap`` with ``--color-mode rgb``): each was dropped
    without a word. Only options typed count: ``--edl-strength 1`` is its default, yet said."""
    specs = {spec.name: spec for spec in settings_fields(type(settings))}
    for name in (n for n in specs if n in given and specs[n].needs):
        switch, values = specs[name].needs
        current = getattr(settings, switch)
        if current in values:
            continue
        wanted = specs[switch].option if specs[switch].kind == "bool" else f"{specs[switch].option} {_or(values)}"
        instead = f", not {current}" if current != specs[switch].default else ""
        raise SettingsError(f"{specs[name].option} needs {wanted}{instead} (it would be ignored)")


@contextmanager
def options_named(cls: type = RenderSettings):
    """A SettingsError raised within (while drawing: ``color_attribute: scan.laz has no attribute
    ...``) names the option, as a bad value does."""
    try:
        yield
    except SettingsError as exc:
        raise named_option(exc, option_of(cls)) from None


def named_option(exc: GigapointError, blame: dict[str, str]) -> GigapointError:
    """``exc`` with the field its message starts with (``color_attribute: ...``, ``video fps
    must ...``) told as the option that set it (``blame``: field or words -> option, e.g.
    ``option_of()``); unchanged otherwise."""
    message = str(exc)
    for name, option in blame.items():
        if message.startswith((f"{name}:", f"{name} ")):  # (not a file named turntable.mp4)
            return type(exc)(f"{option}: {message.removeprefix(f'{name}:').lstrip()}")
    return exc


def with_settings_options(cls: type = RenderSettings, param: str = "settings", refused: dict[str, str] | None = None):
    """Decorator for a typer command: its parameter ``param`` is replaced by one option per field
    of ``cls`` and receives the ``cls`` instance they make. Apply it below ``@app.command()``.
    ``refused``: field -> the message that refuses its option when typed, before any other check
    (section's --ipd is refused as section's, not as needing --stereo, which it refuses too)."""

    def decorate(func):
        sig = inspect.signature(func, eval_str=True)
        own = list(sig.parameters.values())
        names = [p.name for p in own]
        if param not in names:
            raise TypeError(f"{func.__name__} has no parameter {param!r} to receive the settings")
        generated = settings_parameters(cls)
        clash = set(names) & {p.name for p in generated}
        if clash:
            raise TypeError(f"{func.__name__}: parameters {sorted(clash)} clash with settings fields")
        setting_names = [p.name for p in generated]

        @functools.wraps(func)
        def command(**kwargs):
            ctx = kwargs.pop(_CTX)
            values = {name: kwargs.pop(name) for name in setting_names}
            sources = {name: ctx.get_parameter_source(name) for name in setting_names}
            given = {name for name, src in sources.items() if src is not None and src.name not in ("DEFAULT", "DEFAULT_MAP")}
            for name, message in (refused or {}).items():
                if name in given:
                    raise SettingsError(message)
            kwargs[param] = settings_from_options(cls, values, given)
            return func(**kwargs)

        at = names.index(param)
        rest = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own[at + 1 :]]
        ctx = inspect.Parameter(_CTX, inspect.Parameter.KEYWORD_ONLY, annotation=typer.Context)
        params = [*own[:at], *generated, *rest, ctx]
        command.__signature__ = sig.replace(parameters=params)
        command.__annotations__ = {p.name: p.annotation for p in params} | {"return": sig.return_annotation}
        del command.__wrapped__  # typer reads __signature__; nothing should unwrap to func's own
        return command

    return decorate
