// Transparent points, gather: the color of every kept fragment (k-buffer slot) whose point is
// in this page of colors, into the slot's own word, so the resolve reads no point data.
// Colors may span several pages (storage binding limit): one dispatch per page.
//! include keys.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> layers: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> colors: array<u32>;
@group(0) @binding(3) var<storage, read_write> slot_colors: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var s = gid.x; s < params.n_items; s += nwg.x * 256u) {
        let key = layers[s];
        if (!is_empty(key) && key.x >= params.page_first && key.x - params.page_first < params.page_count) {
            slot_colors[s] = colors[key.x - params.page_first];
        }
    }
}
