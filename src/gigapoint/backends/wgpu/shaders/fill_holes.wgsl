// Hole filling (render/passes/holes.py; fill_holes in backends/numba_cpu/pass_kernels.py): a
// depth-aware dilation of the visibility buffer into a second buffer. A pixel that is empty,
// or lies more than the depth gap behind the closest key of its window, takes that key, but
// only when the nearer neighbours surround it: their directions, binned into 16 sectors,
// leave no run of 8 free sectors (no free half-plane). Integer compares and one float32
// multiply, so it equals the CPU pass bit for bit.
//! include keys.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> vis_in: array<vec2<u32>>;
// Window offsets (dx, dy, sector bit, Chebyshev ring), ordered by ring.
@group(0) @binding(2) var<storage, read> window: array<vec4<i32>>;
// Foveated: the window radius of pixel p in byte p (4 a word); unused otherwise.
@group(0) @binding(3) var<storage, read> radii: array<u32>;
@group(0) @binding(4) var<storage, read_write> vis_out: array<vec2<u32>>;

// No run of 8 cyclically adjacent free sectors in the 16-bit occupancy mask.
fn surrounded(occ: u32) -> bool {
    var z = ~(occ | (occ << 16u));
    z = z & (z >> 1u);
    z = z & (z >> 2u);
    z = z & (z >> 4u);
    return z == 0u;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = i32(params.width);
    let h = i32(params.height);
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let k = vis_in[p];
        var radius = i32(params.level);
        if (params.foveated != 0u) {
            radius = i32((radii[p / 4u] >> (8u * (p % 4u))) & 255u);
        }
        // Neighbours count as "nearer" below this depth (bits of positive floats order like
        // the floats); an empty pixel takes any neighbour holding a point.
        var thr = 0x7f800000u;  // +inf
        if (!is_empty(k)) {
            thr = bitcast<u32>(bitcast<f32>(k.y) * params.inv_gap);
        }
        let x = i32(p % params.width);
        let y = i32(p / params.width);
        var best = vec2<u32>(EMPTY_WORD);
        var occ = 0u;
        for (var o = 0u; o < params.n_offsets; o++) {
            let off = window[o];
            if (off.w > radius) {
                break;
            }
            let xx = x + off.x;
            let yy = y + off.y;
            if (xx >= 0 && xx < w && yy >= 0 && yy < h) {
                let n = vis_in[u32(yy * w + xx)];
                if (key_less(n, best)) {
                    best = n;
                }
                if (n.y < thr) {
                    occ |= u32(off.z);
                }
            }
        }
        var out = k;
        if (key_less(best, k) && best.y < thr && surrounded(occ)) {
            out = best;
        }
        vis_out[p] = out;
    }
}
