"""One settings schema (issue #16, part 4): RenderSettings' types and field metadata are the only
place a setting is described; validation, `gigapoint render`'s options and the viewer's panel
are generated from them."""

from __future__ import annotations

import ast
import dataclasses
import enum
import re
from pathlib import Path
from typing import Literal, get_args

import numpy as np
import pytest
import typer

from gigapoint import RenderSettings
from gigapoint.cli import main, render_cmd
from gigapoint.cli.settings_opts import settings_from_options, settings_options, with_settings_options
from gigapoint.errors import SettingsError
from gigapoint.render.colors import COLOR_MODES, COLORMAPS
from gigapoint.render.settings import Colormap, ColorMode, field_types, format_color, help_text, setting, settings_fields
from gigapoint.viewer import protocol as P

SRC = Path(render_cmd.__file__).parents[1]

# a settings class with fields that exist nowhere else: no CLI or viewer code mentions them
Extended = dataclasses.make_dataclass(
    "Extended",
    [
        ("sparkle_gain", float, setting(2.5, "How much sparkle.", min=0.25, max=7.5)),
        ("glint", Literal["none", "soft", "hard"], setting("none", "Glint style.", group="execution")),
        ("glint_passes", int, setting(3, "Glint passes.", min=1, max=9, option="--passes", viewer=False)),
        ("glow", bool, setting(True, "Glow around points.", group="lod")),
        ("halo_range", tuple[float, float] | None, setting(None, "'low,high' halo depths.")),
        ("rim_color", tuple[int, int, int, int], setting((10, 20, 30, 255), "Rim color.", kind="color")),
    ],
    bases=(RenderSettings,),
    frozen=True,
)
NEW = ["sparkle_gain", "glint", "glint_passes", "glow", "halo_range", "rim_color"]


def command_of(cls):
    """A typer command made only of ``cls``' generated options; returns (command, received settings)."""
    app = typer.Typer()
    got = []

    @app.command()
    @with_settings_options(cls)
    def show(settings: RenderSettings) -> None:
        got.append(settings)

    return typer.main.get_command(app), got


def parse(cls, *args):
    cmd, got = command_of(cls)
    cmd.main(list(args), standalone_mode=False)
    return got[-1]


def render_params() -> dict:
    from gigapoint.cli import app, commands  # noqa: F401  (commands registers `render`)

    render = typer.main.get_command(app).commands["render"]
    return {p.name: p for p in render.params}, render


# --- a field added to the dataclass appears in the CLI and the viewer with no other edit ---------
def test_new_fields_become_cli_options():
    opts = {o.name: o for o in settings_options(Extended)}
    assert set(NEW) <= set(opts)
    assert (opts["sparkle_gain"].option, opts["glint_passes"].option, opts["glow"].decl) == (
        "--sparkle-gain",
        "--passes",
        "--glow/--no-glow",
    )
    assert get_args(opts["glint"].annotation) == ("none", "soft", "hard")
    assert opts["glint"].panel == "Execution" and opts["glow"].panel == "Precision, culling and level of detail"

    s = parse(
        Extended, "--sparkle-gain", "7.5", "--glint", "hard", "--passes", "9", "--no-glow", "--halo-range", "1,2.5", "--rim-color", "white"
    )
    assert (s.sparkle_gain, s.glint, s.glint_passes, s.glow, s.halo_range, s.rim_color) == (
        7.5,
        "hard",
        9,
        False,
        (1.0, 2.5),
        (255, 255, 255, 255),
    )
    d = parse(Extended)  # every default is the dataclass' own
    assert d == Extended() and d.glow is True and d.glint_passes == 3
    assert parse(Extended, "--edl", "--point-budget", "5") == Extended(edl=True, point_budget=5)  # the base fields too


def test_new_fields_appear_in_the_viewer_schema():
    schema = {d["name"]: d for d in P.settings_schema(Extended)}
    assert schema["sparkle_gain"] == {
        "name": "sparkle_gain",
        "label": "sparkle gain",
        "help": "How much sparkle.",  # from the metadata: make_dataclass has no source a regex could read
        "nullable": False,
        "kind": "float",
        "min": 0.25,
        "max": 7.5,
        "default": 2.5,
    }
    assert schema["glint"]["kind"] == "enum" and schema["glint"]["choices"] == ["none", "soft", "hard"]
    assert schema["glow"]["kind"] == "bool" and schema["glow"]["default"] is True
    assert (schema["halo_range"]["kind"], schema["halo_range"]["nullable"]) == ("range", True)
    assert schema["rim_color"]["kind"] == "color" and schema["rim_color"]["default"] == [10, 20, 30, 255]
    assert "glint_passes" not in schema  # viewer=False
    s = P.apply_settings(Extended(), {"glint": "soft", "sparkle_gain": 1, "halo_range": [0, 3]})
    assert (s.glint, s.sparkle_gain, s.halo_range) == ("soft", 1, (0.0, 3.0))
    with pytest.raises(P.ProtocolError, match=r"sparkle_gain must be a number in \[0.25, 7.5\], got 9$"):
        P.apply_settings(Extended(), {"sparkle_gain": 9})


def test_range_messages_say_numbers_compactly_and_exactly():
    """A bound of 2e12 was said '2000000000000.0' (and --ipd 1e13 '10000000000000.0'): numbers read
    '%g' short where that is the same number, in full where '%g' would round them."""
    for value, said in ((1e13, "1e+13"), (-0.5, "-0.5"), (-123456789.5, "-123456789.5"), (-1 / 3, "-0.3333333333333333"), ("far", "'far'")):
        with pytest.raises(SettingsError, match=rf"^ipd must be a number in \[0, 2e\+12\], got {re.escape(said)}$"):
            RenderSettings(ipd=value)
    with pytest.raises(SettingsError, match=r"^convergence must be a number in \(0, 2e\+12\], got 0$"):
        RenderSettings(convergence=0.0)
    with pytest.raises(SettingsError, match=r"^point_size must be an integer in \[1, 64\], got 1000000000000$"):
        RenderSettings(point_size=10**12)


def test_new_fields_are_validated_from_type_and_metadata():
    with pytest.raises(SettingsError, match=r"^glint must be one of none, soft, hard, got 'dull'$"):
        Extended(glint="dull")
    with pytest.raises(SettingsError, match=r"^glint_passes must be an integer in \[1, 9\], got 2.5$"):
        Extended(glint_passes=2.5)
    with pytest.raises(SettingsError, match=r"^glow must be true or false, got 'yes'$"):
        Extended(glow="yes")
    with pytest.raises(SettingsError, match=r"^halo_range must be finite with high > low"):
        Extended(halo_range=(2, 1))
    with pytest.raises(SettingsError, match=r"^rim_color: cannot read color"):
        Extended(rim_color="no-such-color")
    assert Extended(glint_passes=4.0).glint_passes == 4 and type(Extended(glint_passes=4.0).glint_passes) is int


def test_every_boolean_setting_takes_python_and_numpy_booleans_only():
    """edl=2 was taken (and kept as 2) while the check meant true or false; numpy's booleans (a
    mask's value) are taken, as Python's bool."""
    import numpy as np

    names = [spec.name for spec in settings_fields(RenderSettings) if spec.kind == "bool"]
    assert {"edl", "hqs", "lighting", "adaptive_precision", "frustum_culling", "fill_holes_foveated"} <= set(names)
    for name in names:
        for value in (True, np.True_, False, np.False_):
            got = getattr(RenderSettings(**{name: value}), name)
            assert got is bool(value), name  # (numpy's made Python's)
        for bad in (2, 1, 0, "no", None, 1.0):
            with pytest.raises(SettingsError, match=rf"^{name} must be true or false, got {re.escape(repr(bad))}$"):
                RenderSettings(**{name: bad})


def test_a_field_whose_annotation_cannot_be_resolved_falls_back_to_its_default():
    class Mode(enum.Enum):  # local: this module's string annotation "Mode" cannot be resolved
        A = "a"
        B = "b"

    @dataclasses.dataclass(frozen=True)
    class Local(RenderSettings):
        mode: Mode = Mode.A

    assert "mode" not in field_types(Local) or field_types(Local)["mode"] is Mode
    assert Local(mode="b").mode is Mode.B
    assert parse(Local, "--mode", "b").mode is Mode.B
    with pytest.raises(SettingsError, match="^--mode: mode must be one of a, b, got 'c'$"):
        parse(Local, "--mode", "c")


# --- choices, ranges and defaults in the CLI come from the schema --------------------------------
def test_every_field_is_a_render_option_with_its_help_default_choices_and_range():
    params, render = render_params()
    ctx = typer.Context(render)
    for spec in settings_fields(RenderSettings):
        p = params[spec.name]
        assert spec.option in p.opts, spec.name
        assert help_text(RenderSettings, spec, lambda other: other.option).replace("[", "\\[") in p.help
        if spec.kind == "enum":
            assert [c.value for c in p.shell_complete(ctx, "")] == [str(c) for c in spec.choices]
            assert spec.choices == get_args(field_types(RenderSettings)[spec.name])
        if spec.min is not None:
            assert (
                f"{spec.min}{'<' if spec.exclusive_min else '<='}x" in p.help
                or f"x{'>' if spec.exclusive_min else '>='}{spec.min}" in p.help
            )
        if spec.max is not None:
            assert f"x<={spec.max}]" in p.help
        shown = {"color": lambda v: format_color(v), "classes": lambda v: ",".join(map(str, v)) or None}.get(spec.kind, lambda v: v)
        assert p.default == shown(spec.default), spec.name
    assert params["point_budget"].default == RenderSettings().point_budget
    assert params["adaptive_precision"].secondary_opts == ["--no-adaptive-precision"]
    assert params["fill_holes_foveated"].opts == ["--foveated"]


def test_the_choices_are_the_literal_types():
    assert COLOR_MODES == get_args(ColorMode) and COLORMAPS == get_args(Colormap)
    assert {s.name: s.choices for s in settings_fields() if s.kind == "enum"} == {
        "backend": ("auto", "cpu", "wgpu"),
        "color_mode": COLOR_MODES,
        "colormap": COLORMAPS,
        "point_shape": ("square", "round"),
        "size_mode": ("auto", "adaptive", "fixed", "attenuated"),
        "supersample": (1, 2, 4),
        "supersample_filter": ("box", "lanczos"),
        "stereo": ("none", "side-by-side", "anaglyph"),
    }


def test_point_budget_default_is_written_once():
    sources = {
        p.name: p.read_text() for p in [SRC / "cli" / "render_cmd.py", SRC / "cli" / "quality_opts.py", SRC / "cli" / "settings_opts.py"]
    }
    sources["protocol.py"] = (SRC / "viewer" / "protocol.py").read_text()
    for name, text in sources.items():
        assert "10_000_000" not in text and "10000000" not in text, name
    settings_src = (SRC / "render" / "settings.py").read_text()
    assert settings_src.count("10_000_000") == 1
    assert parse(RenderSettings).point_budget == RenderSettings().point_budget == 10_000_000


# --- a bad value is one line naming its option ---------------------------------------------------
def _bad_value(spec):
    if spec.kind == "enum":
        return "bogus"
    if spec.kind in ("int", "float") and spec.min is not None:
        return str(spec.min - 1)
    if spec.kind in ("int", "float") and spec.max is not None:
        return str(spec.max + 1)
    if spec.kind == "range":
        return "3,1"
    if spec.kind == "color":
        return "no-such-color"
    if spec.kind == "classes":
        return "7,256"
    return None


@pytest.mark.parametrize("spec", [s for s in settings_fields(RenderSettings) if _bad_value(s) is not None], ids=lambda s: s.name)
def test_a_bad_value_names_its_option(spec, tmp_path, capsys):
    out = tmp_path / "x.png"
    assert main(["render", str(tmp_path / "missing.npy"), "-o", str(out), spec.option, _bad_value(spec)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {spec.option}: ") and err.count("\n") == 1, err
    assert not out.exists()


def test_text_a_number_option_cannot_read_is_a_one_line_error_too(tmp_path, capsys):
    assert main(["render", str(tmp_path / "missing.npy"), "-o", str(tmp_path / "x.png"), "--edl-strength", "lots"]) == 1
    assert capsys.readouterr().err == "error: --edl-strength: edl_strength must be a number in [0, 10000], got 'lots'\n"


def test_image_size_errors_name_their_option(tmp_path, capsys):
    for args, option in ((["-W", "0"], "--width"), (["-H", "100000"], "--height"), (["--fov", "0"], "--fov")):
        assert main(["render", str(tmp_path / "missing.npy"), "-o", str(tmp_path / "x.png"), *args]) == 1
        assert capsys.readouterr().err.startswith(f"error: {option}: ")


# --- the --point-world-size shorthand ------------------------------------------------------------
def test_point_world_size_alone_means_attenuated_points_of_at_most_16_px():
    s = parse(RenderSettings, "--point-world-size", "0.5")
    assert (s.size_mode, s.point_world_size, s.point_size) == ("attenuated", 0.5, 16)
    s = parse(RenderSettings, "--point-world-size", "0.5", "--point-size", "4")
    assert (s.size_mode, s.point_size) == ("attenuated", 4)
    s = parse(RenderSettings, "--point-world-size", "0.5", "--size-mode", "auto", "--point-size", "1")
    assert (s.size_mode, s.point_size) == ("auto", 1)  # given too: kept
    with pytest.raises(SettingsError, match=r"^--point-world-size needs --size-mode auto or attenuated, not fixed \(it would be ignored\)$"):
        parse(RenderSettings, "--point-world-size", "0.5", "--size-mode", "fixed", "--point-size", "1")
    assert parse(RenderSettings, "--size-mode", "attenuated", "--point-world-size", "2").point_size == 16
    assert parse(RenderSettings, "--size-mode", "attenuated", "--point-world-size", "2", "--point-size", "1").point_size == 1
    with pytest.raises(SettingsError, match=r"^--point-world-size: size_mode 'attenuated' needs point_world_size > 0"):
        parse(RenderSettings, "--point-world-size", "0")
    # without a command line nothing is implied (the default 'auto' then draws them attenuated)
    assert settings_from_options(RenderSettings, {"point_world_size": 0.5}).size_mode == "auto"


def test_render_keywords_imply_what_their_options_do():
    # gp.render(c, point_world_size=20) drew 1-px points (attenuated, at most point_size 1) where
    # --point-world-size 20 drew up to 16 px; color_attribute="intensity" kept the rgb colours
    base = RenderSettings()
    s = base.given(point_world_size=0.5)
    assert (s.point_sizing, s.point_world_size, s.point_size) == ("attenuated", 0.5, 16)
    assert base.given(point_world_size=0.5, point_size=4).point_size == 4  # given too: kept
    assert base.given(color_attribute="intensity").color_mode == "attribute"
    assert base.given(color_attribute="intensity", color_mode="elevation").color_mode == "elevation"
    held = RenderSettings(color_mode="intensity", point_size=3)  # already set away from the defaults: kept
    assert held.given(color_attribute="intensity").color_mode == "intensity"
    assert held.given(point_world_size=0.5).point_size == 3
    assert base.given(color_attribute=None, point_world_size=0.0) == base  # a default given implies nothing
    assert base.replace(color_attribute="intensity").color_mode == "rgb"  # replace (the viewer's) sets the field alone


# --- layering -------------------------------------------------------------------------------------
def test_settings_module_imports_no_upper_layer():
    tree = ast.parse((SRC / "render" / "settings.py").read_text())
    modules = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    modules += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    assert not [m for m in modules if any(layer in m.split(".") for layer in ("backends", "lod", "viewer", "cli"))], modules


@pytest.mark.parametrize("value", ["inf", "nan,1,1", "0.5,0.5,0.5", "300,1,1", "1,2", (1.5, 2, 3)])
def test_a_colour_of_numbers_that_are_not_whole_bytes_is_refused(value):
    """'inf' was an internal OverflowError; '0.5,0.5,0.5' (channels as 0..1) was black, silently."""
    with pytest.raises(SettingsError, match=r"^background: color needs 3 or 4 whole numbers in 0\.\.255, got "):
        RenderSettings(background=value)


def test_colours_read_as_names_hex_and_whole_numbers():
    assert RenderSettings(background="1,2,3").background == (1, 2, 3, 255)
    assert RenderSettings(background=(1, 1, 1)).background == (1, 1, 1, 255)
    assert RenderSettings(background=(1.0, 2.0, 3.0, 4.0)).background == (1, 2, 3, 4)
    assert RenderSettings(background=(255.0, 0.0, 0.0)).background == (255, 0, 0, 255)
    assert RenderSettings(background=(0.0, 0.0, 0.0)).background == (0, 0, 0, 255)  # (black on either scale)
    assert RenderSettings(background="#102030").background == (16, 32, 48, 255)
    assert RenderSettings(background="white").background == (255, 255, 255, 255)


@pytest.mark.parametrize(
    "value, scaled",
    [((1.0, 1.0, 1.0), "(255, 255, 255) or 'white'"), ((0.5, 0.5, 0.5), "(128, 128, 128) or 'gray'"), ("1.0,0,0", "(255, 0, 0) or '#ff0000'"),
     (np.array([0.0, 0.0, 1.0, 0.5]), "(0, 0, 255, 128) or '#0000ff80'")],
)
def test_a_colour_of_floats_within_0_to_1_is_refused_with_its_0_to_255_values(value, scaled):
    """background=(1.0, 1.0, 1.0) (0..1 channels: white) was read as 0..255: near black, without a word."""
    with pytest.raises(SettingsError) as err:
        RenderSettings(background=value)
    assert str(err.value) == f"background: color needs 3 or 4 whole numbers in 0..255, got {value!r} (0..1 channels: give {scaled})"


def test_the_viewer_panel_names_fields_by_their_labels():
    """The panel's tooltips said 'values of color_attribute' and 'fixed: point_size pixels'."""
    helps = {d["name"]: d["help"] for d in P.settings_schema(RenderSettings)}
    assert helps["attribute_range"] == "'low,high' values of color attribute mapped onto the colormap (default: 2nd..98th percentile)."
    assert "fixed: point size pixels (with point size 1: the exact one-pixel render); attenuated: point world size, at most point size" in helps["size_mode"]
    names = {spec.name for spec in settings_fields(RenderSettings)}
    assert not [(n, h) for n, h in helps.items() if names & set(re.findall(r"\b[a-z]+(?:_[a-z]+)+\b", h))]


def test_short_hex_colours_read_as_css_does_and_a_bad_name_lists_the_names():
    """'#fff' was 'cannot read color'; 'red' was refused without saying which names there are."""
    assert RenderSettings(background="#fff").background == (255, 255, 255, 255)
    assert RenderSettings(background="#1a2C").background == (0x11, 0xAA, 0x22, 0xCC)
    with pytest.raises(SettingsError) as err:
        RenderSettings(background="red")
    assert str(err.value) == "background: cannot read color 'red' (use black, white, gray, grey, darkgray, skyblue, potree, #rrggbb, #rgb or r,g,b)"
    with pytest.raises(SettingsError, match=r"^background: cannot read color '#ggg' \(use black, "):
        RenderSettings(background="#ggg")
