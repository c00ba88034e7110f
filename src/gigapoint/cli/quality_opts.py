"""Image-quality options of `gigapoint render` turned into RenderSettings fields (issue #5)."""

from __future__ import annotations

from ..errors import GigapointError, SettingsError

# every image-quality field of RenderSettings -> the `gigapoint render` option that sets it
OPTION_OF = {
    "color_mode": "--color-mode", "colormap": "--colormap", "elevation_range": "--elevation-range",
    "intensity_range": "--intensity-range", "edl": "--edl", "edl_strength": "--edl-strength", "edl_radius": "--edl-radius",
    "fill_holes": "--fill-holes", "fill_holes_foveated": "--foveated", "hqs": "--hqs", "hqs_depth_tolerance": "--hqs-depth-tolerance",
    "point_size": "--point-size", "point_shape": "--point-shape", "size_mode": "--point-world-size",
    "point_world_size": "--point-world-size", "splat_softness": "--splat-softness", "supersample": "--supersample",
    "supersample_filter": "--supersample-filter", "stereo": "--stereo", "ipd": "--ipd", "convergence": "--convergence",
    "lighting": "--lighting", "shininess": "--shininess",
}  # fmt: skip


def _pair(name: str, text: str | None):
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise GigapointError(f"--{name}: expected 'low,high', got {text!r}") from None
    return (lo, hi)


def quality_settings(*, color_mode, colormap, elevation_range, intensity_range, edl, edl_strength, edl_radius, fill_holes, foveated, hqs,
                     hqs_depth_tolerance, point_size, point_shape, point_world_size, splat_softness, supersample, supersample_filter,
                     stereo, ipd, convergence, lighting, shininess) -> dict:  # fmt: skip
    """RenderSettings keyword arguments of the CLI's quality options (validated by RenderSettings)."""
    out = {
        "color_mode": color_mode, "colormap": colormap, "elevation_range": _pair("elevation-range", elevation_range),
        "intensity_range": _pair("intensity-range", intensity_range), "edl": edl, "edl_strength": edl_strength, "edl_radius": edl_radius,
        "fill_holes": fill_holes, "fill_holes_foveated": foveated, "hqs": hqs, "hqs_depth_tolerance": hqs_depth_tolerance,
        "point_size": point_size, "point_shape": point_shape, "splat_softness": splat_softness, "supersample": supersample,
        "supersample_filter": supersample_filter, "stereo": stereo, "ipd": ipd, "convergence": convergence, "lighting": lighting,
        "shininess": shininess,
    }  # fmt: skip
    if point_world_size is not None:  # attenuated points: --point-size is the largest size (16 px unless given)
        out.update(size_mode="attenuated", point_world_size=point_world_size, point_size=point_size if point_size > 1 else 16)
    return out


def apply_quality(settings, **options):
    """``settings`` with the quality options applied; a bad value is a SettingsError naming the option."""
    try:
        return settings.replace(**quality_settings(**options))
    except SettingsError as exc:
        field = str(exc).split(" ", 1)[0].rstrip(":")
        if field in OPTION_OF:
            raise SettingsError(f"{OPTION_OF[field]}: {exc}") from None
        raise


def prepare_cloud(cloud, settings) -> None:
    """Estimate normals when lighting or the normal color mode needs them and the cloud has none."""
    if not (settings.lighting or settings.color_mode == "normal"):
        return
    from ..render.colors import normals_of

    if getattr(cloud, "attributes", None) is not None and normals_of(cloud) is None and hasattr(cloud, "positions"):
        from ..render.normals import estimate_normals

        estimate_normals(cloud)
