// High-quality shading, resolve: the rounded mean color (sum + n / 2) / n per channel where
// some point contributed; other pixels keep the color they have (the plain resolve's:
// empty, or filled by hole filling). In place on the image.
//! include keys.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> accum: array<u32>;
@group(0) @binding(2) var<storage, read_write> image: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let n = accum[4u * params.n_items + p];
        if (n != 0u) {
            let h = n >> 1u;
            var c = 0u;
            for (var k = 0u; k < 4u; k++) {
                c |= ((accum[4u * p + k] + h) / n) << (8u * k);
            }
            image[p] = c;
        }
    }
}
