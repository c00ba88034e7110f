// High-quality shading, accumulate (render/passes/hqs.py; hqs_accumulate in
// backends/numba_cpu/pass_kernels.py): the selected batches are projected again exactly as in the
// depth pass, and every point within the relative depth tolerance of its pixel's closest
// depth adds weight x RGBA and the weight, at every pixel of its footprint.
//
// Sums are u32 atomics, one per channel: exact while weight x 255 x points per pixel < 2^32,
// i.e. up to 2^24 points a pixel (hard splats, weight 1) or 2^24 / 15 (soft splats). The
// count is u32 too. Commutative integer sums: the image does not depend on thread order.
//! include common.wgsl
//! include keys.wgsl

@group(0) @binding(7) var<storage, read> visibility: array<vec2<u32>>;
// Colors of this page's points (the same page as the point words).
@group(0) @binding(8) var<storage, read> colors: array<u32>;
// Per pixel p: the channel sums at 4p .. 4p+3, the summed weight at 4 * pixels + p.
@group(0) @binding(9) var<storage, read_write> accum: array<atomic<u32>>;

// Kraft 2019 eq. 3.1 soft-splat weight of footprint row `row` (0..15; 1 for hard splats).
// Fixed sizes: precomputed on the host in float64 (soft_weight in render/params.py); attenuated
// sizes (weight -1): computed here in float32, so it may differ by one at rounding edges.
fn splat_weight(row: u32, size: f32) -> u32 {
    let r = footprint[row];
    if (r.w >= 0) {
        return u32(r.w);
    }
    let d = sqrt(f32(r.x * r.x + r.y * r.y));
    var o = 1.0;
    if (d > 0.0) {
        o = 1.0 - pow(d / (0.5 * size), params.softness);
    }
    return u32(max(0.0, 15.0 * o + 0.5));
}

fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    let key = visibility[pixel];
    if (is_empty(key) || !(bitcast<f32>(depth_bits) <= bitcast<f32>(key.y) * params.tol1)) {
        return;
    }
    let w = splat_weight(row, size);
    if (w == 0u) {
        return;
    }
    let c = colors[index - params.page_first];
    for (var k = 0u; k < 4u; k++) {
        atomicAdd(&accum[4u * pixel + k], w * channel(c, k));
    }
    atomicAdd(&accum[4u * params.width * params.height + pixel], w);
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    draw_batch(wid, nwg, lid);
}
