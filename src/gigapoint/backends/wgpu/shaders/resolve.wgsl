// Resolve pass: each pixel's color from its winning point index (visibility-buffer
// shading: colors are read for visible points only), or the background.
// Colors may span several pages (storage binding limit): one dispatch per page, each
// writing the pixels whose index falls in its page; every dispatch writes the background.
//! include keys.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> visibility: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> colors: array<u32>;
@group(0) @binding(3) var<storage, read_write> image: array<u32>;
// per-block palettes (color_bits 8: core/palette.py) of the page's blocks; a dummy otherwise
@group(0) @binding(4) var<storage, read> palette: array<u32>;

// RGBA8 of point ``g`` (global index; ``i`` within the page) of per-block palettes: entry
// ``index`` of its block's palette, palette_rgba in core/palette.py.
fn palette_rgba(g: u32, i: u32) -> u32 {
    let index = (colors[i >> 2u] >> (8u * (i & 3u))) & 0xffu;
    return palette[((g >> params.palette_shift) << 8u) + index - params.palette_first];
}

// RGBA8 (opaque) of an RGB565 color: rgb565_rgba in core/compact.py (bit replication).
fn rgb565_rgba(c: u32) -> u32 {
    let r = c >> 11u;
    let g = (c >> 5u) & 63u;
    let b = c & 31u;
    return ((r << 3u) | (r >> 2u)) | (((g << 2u) | (g >> 4u)) << 8u) | (((b << 3u) | (b >> 2u)) << 16u) | 0xff000000u;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let key = visibility[p];
        if (is_empty(key)) {
            image[p] = params.background;
        } else if (key.x >= params.page_first && key.x - params.page_first < params.page_count) {
            let i = key.x - params.page_first;
            if (params.color_bits == 8u) {
                image[p] = palette_rgba(key.x, i);
            } else if (params.color_bits == 16u) {
                image[p] = rgb565_rgba((colors[i >> 1u] >> (16u * (i & 1u))) & 0xffffu);
            } else {
                image[p] = colors[i];
            }
        }
    }
}
