// Transparent points, accumulate (render/passes/transparency.py; transparency_shade in
// backends/numba_cpu/pass_kernels.py): the selected batches are projected again exactly as in
// the depth pass, and every fragment goes into its pixel's k-buffer (the TR_LAYERS smallest keys
// depth bits << 32 | point index, ascending) and adds its alpha a, a x color and its revealage
// term to the pixel's u64 sums. The k-buffer insertion is a cascade of 64-bit atomicMin whose
// loser moves on to the next slot: whatever order the fragments come in, the slots end up
// holding the smallest keys in order. Integer sums: the image does not depend on thread order.
// Needs 64-bit atomics that return their old value (wgpu's shader-int64-atomic-all-ops).
//! include common.wgsl
//! include transparency_alphas.wgsl

const EMPTY64: u64 = 0xfffffffffffffffflu;

@group(0) @binding(7) var<storage, read_write> layers: array<atomic<u64>>;
// Colors of this page's points (the same page as the point words).
@group(0) @binding(8) var<storage, read> colors: array<u32>;
// Per pixel p: sums[5p] = sum of a, 5p+1..5p+3 = sum of a x r, g, b, 5p+4 = revealage.
@group(0) @binding(9) var<storage, read_write> sums: array<atomic<u64>>;
// params.n_items rows (first point, 8-bit alpha, revealage term, -): transparency_alphas.wgsl
@group(0) @binding(10) var<storage, read> alphas: array<vec4<u32>>;

fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    let base = pixel * TR_LAYERS;
    var key = (u64(depth_bits) << 32u) | u64(index);
    // most fragments of a dense pixel lie behind its last kept one: a plain load rejects them
    if (key < atomicLoad(&layers[base + TR_LAYERS - 1u])) {
        for (var i = 0u; i < TR_LAYERS; i++) {
            let old = atomicMin(&layers[base + i], key);
            if (old == EMPTY64) {
                break;
            }
            key = select(key, old, old > key);  // the larger of the two moves on
        }
    }
    let al = alpha_row(index, params.n_items).yz;
    let a = u64(al.x);
    let c = colors[index - params.page_first];
    atomicAdd(&sums[5u * pixel], a);
    atomicAdd(&sums[5u * pixel + 1u], a * u64(c & 255u));
    atomicAdd(&sums[5u * pixel + 2u], a * u64((c >> 8u) & 255u));
    atomicAdd(&sums[5u * pixel + 3u], a * u64((c >> 16u) & 255u));
    atomicAdd(&sums[5u * pixel + 4u], (u64(al.y) << TR_COUNT_BITS) + 1lu);
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    draw_batch(wid, nwg, lid);
}
