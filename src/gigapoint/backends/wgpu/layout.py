"""GPU-side binary layouts: numpy dtypes, and the WGSL struct text derived from them.

The dtypes are the single definition; ``wgsl_struct`` writes the matching WGSL struct and
checks that WGSL's alignment rules place every field at the numpy offset, so a layout can
never drift between host and shader (DESIGN.md: layouts defined once, derived elsewhere).
"""

from __future__ import annotations

import numpy as np

#: Most views one draw dispatch writes (stereo: 2; the size of Params' view table); more
#: views are drawn in groups of this many.
MAX_VIEWS = 8

#: One record per selected batch and view, rebuilt every frame from the Selection. A dispatch
#: of n batches and V views reads records batch_offset.. : view v's record of its b-th batch
#: is record batch_offset + v * n + b.
#: ``rows`` is the batch's float32 4x4 matrix (10-bit grid units -> x', y', w, depth), row-major,
#: so the shader can repeat the CPU kernel's ``m[i,0]*x + m[i,1]*y + m[i,2]*z + m[i,3]`` exactly.
GPU_BATCH_DTYPE = np.dtype(
    [
        ("rows", "<f4", (4, 4)),
        ("first", "<u4"),  # global index of the batch's first point (the visibility key's low word)
        ("local_first", "<u4"),  # the same point's index inside its page's buffers
        ("count", "<u4"),
        ("bits", "<u4"),  # precision: 10, 20 or 30
        # the compact layout (core/compact.py): the batch's extension stream starts at this u32 of
        # the page's stream (bound where three-word pages bind ``med``)
        ("ext_first", "<u4"),
        ("code", "<u4"),  # its e_x | e_y << 8 | e_z << 16; FULL_LAYOUT: three words (med, high)
        ("_pad0", "<u4"),
        ("_pad1", "<u4"),
    ]
)

#: ``code`` of a batch in three u32 words
FULL_LAYOUT = 0xFFFFFFFF

#: Per-dispatch uniforms shared by every pass (each pass reads the fields it needs).
PARAMS_DTYPE = np.dtype(
    [
        ("width", "<u4"),
        ("height", "<u4"),
        ("near", "<f4"),  # raster, HQS: clip range of view 0 (of the only view, but in multi-view draws)
        ("far", "<f4"),
        ("batch_offset", "<u4"),  # raster: first record of this dispatch in the batch buffer
        ("batch_count", "<u4"),  # raster: batches in this dispatch (one workgroup each; records per view)
        ("n_items", "<u4"),  # clear / resolve: number of u32 words / pixels
        ("page_first", "<u4"),  # resolve, HQS, lighting: global index of the page's first point
        ("page_count", "<u4"),  # resolve, lighting: points in the page
        ("background", "<u4"),  # resolve: RGBA8 background
        ("fill", "<u4"),  # clear: the u32 written to every word
        ("fp_count", "<u4"),  # raster, HQS: rows of the splat footprint (1: one-pixel points)
        ("point_size", "<f4"),  # raster, HQS: splat size in pixels (the clamp when attenuated)
        ("atten", "<f4"),  # raster, HQS: perspective size scale (0: fixed size)
        ("softness", "<f4"),  # HQS: soft-splat falloff exponent (0: hard)
        ("tol1", "<f4"),  # HQS: 1 + relative depth tolerance
        ("n_offsets", "<u4"),  # EDL, hole filling: neighbour offsets in the table
        ("edl_scale", "<f4"),  # EDL: -300 strength / n / ln 2
        ("level", "<u4"),  # hole filling: window radius (the largest when foveated)
        ("foveated", "<u4"),  # hole filling: 1 = radius per pixel from the radius map
        ("inv_gap", "<f4"),  # hole filling: 1 / (1 + depth gap)
        ("one_dir", "<u4"),  # lighting: 1 = one view direction for all pixels (orthographic)
        ("ambient", "<f4"),  # lighting: Blinn-Phong terms
        ("diffuse", "<f4"),
        ("specular", "<f4"),
        ("shininess", "<f4"),
        ("step", "<u4"),  # raster: draw every step-th point of each batch (0 or 1: all)
        ("color_bits", "<u4"),  # resolve: 16 = colors are u16 RGB565 (a compact cloud's), 8 = u8 palette indices, else u32 RGBA8
        ("palette_shift", "<u4"),  # resolve (color_bits 8): a palette of PALETTE_SIZE colours serves 2^shift points
        ("palette_first", "<u4"),  # resolve (color_bits 8): global index of the page's palette binding's first entry
        ("opaque_zero", "<u4"),  # raster, HQS, EDL: always 0, a value the shader compiler cannot see (exact.wgsl, product)
        ("_pad_p1", "<u4"),
        ("views", "<f4", (MAX_VIEWS, 4)),  # raster: view v's (near, far, -, -) (entry 0 repeats near, far)
    ]
)
# numpy scalar kind -> WGSL scalar (4-byte types only: WGSL has no portable 64-bit scalar)
_SCALARS = {("u", 4): "u32", ("i", 4): "i32", ("f", 4): "f32"}


def _wgsl_field(base: np.dtype, shape: tuple[int, ...]) -> tuple[str, int, int]:
    """(WGSL type, alignment, size) of a numpy field (scalar, vector or array of them)."""
    key = (base.kind, base.itemsize)
    if key not in _SCALARS:
        raise TypeError(f"numpy type {base} has no WGSL equivalent (only 4-byte u32/i32/f32)")
    scalar = _SCALARS[key]
    if not shape:
        return scalar, 4, 4
    *outer, inner = shape
    if inner in (2, 4):  # vec2 / vec4 (no vec3: its 16-byte alignment would leave holes)
        t, align, size = f"vec{inner}<{scalar}>", 4 * inner, 4 * inner
    else:
        t, align, size = f"array<{scalar}, {inner}>", 4, 4 * inner
    for n in reversed(outer):
        t, size = f"array<{t}, {n}>", size * n  # stride = element size (a multiple of its alignment)
    return t, align, size


def wgsl_struct(name: str, dtype: np.dtype) -> str:
    """WGSL ``struct name {...}`` with the numpy layout of ``dtype``, checked field by field."""
    lines = ["// generated from numpy dtype by gigapoint.backends.wgpu.layout; do not edit", f"struct {name} {{"]
    offset = 0
    struct_align = 4
    for field in dtype.names:
        base, np_offset = dtype.fields[field][:2]
        shape = base.shape
        base = base.base
        t, align, size = _wgsl_field(base, shape)
        offset = -(-offset // align) * align
        if offset != np_offset:
            raise TypeError(f"{name}.{field}: WGSL would place it at byte {offset}, numpy has it at {np_offset}; reorder the dtype")
        lines.append(f"    {field}: {t},")
        offset += size
        struct_align = max(struct_align, align)
    total = -(-offset // struct_align) * struct_align
    if total != dtype.itemsize:
        raise TypeError(f"{name}: WGSL size would be {total} bytes, numpy itemsize is {dtype.itemsize}")
    lines.append("}")
    return "\n".join(lines) + "\n"


#: The structs every shader sees (prepended by the loader).
STRUCTS = {"BatchRecord": GPU_BATCH_DTYPE, "Params": PARAMS_DTYPE}


def wgsl_structs() -> str:
    """The structs, and the size of Params' view table (shaders size their per-view arrays by it)."""
    head = f"const MAX_VIEWS: u32 = {MAX_VIEWS}u;\n"
    return head + "\n".join(wgsl_struct(n, d) for n, d in STRUCTS.items())
