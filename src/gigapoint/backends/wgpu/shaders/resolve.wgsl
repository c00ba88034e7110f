// Resolve pass: each pixel's color from its winning point index (visibility-buffer
// shading: colors are read for visible points only), or the background.
// Colors may span several pages (storage binding limit): one dispatch per page, each
// writing the pixels whose index falls in its page; every dispatch writes the background.

@group(0) @binding(0) var<uniform> params: Params;
// One u64 per pixel seen as (low, high) u32 words: x = point index, y = depth bits.
@group(0) @binding(1) var<storage, read> visibility: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> colors: array<u32>;
@group(0) @binding(3) var<storage, read_write> image: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let key = visibility[p];
        if (key.x == 0xffffffffu && key.y == 0xffffffffu) {
            image[p] = params.background;
        } else if (key.x >= params.page_first && key.x - params.page_first < params.page_count) {
            image[p] = colors[key.x - params.page_first];
        }
    }
}
