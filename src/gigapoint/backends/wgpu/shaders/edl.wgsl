// Eye-dome lighting, step 2 (render/passes/edl.py; edl in backends/numba_cpu/pass_kernels.py): each
// of the neighbours at the offsets adds max(0, log2 d - log2 d_n) (100 if this pixel is
// empty); the color is scaled by 2^(sum x edl_scale), 2^y from the exponent bits and a
// degree-6 Taylor polynomial. The same float32 operations in the same order as the CPU
// kernel (products rounded before they are added: exact.wgsl); in place on the image.
//! include exact.wgsl

@group(0) @binding(0) var<uniform> params: Params;
// log_depth.wgsl's output: (log2 depth, 1) per pixel, (0, 0) where empty.
@group(0) @binding(1) var<storage, read> logd: array<vec2<f32>>;
// Neighbour offsets (dx, dy, 0, 0).
@group(0) @binding(2) var<storage, read> offsets: array<vec4<i32>>;
@group(0) @binding(3) var<storage, read_write> image: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = i32(params.width);
    let h = i32(params.height);
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let c = logd[p].x;
        let ec = 1.0 - logd[p].y;  // 1 where empty
        let x = i32(p % params.width);
        let y = i32(p / params.width);
        var acc = 0.0;
        for (var o = 0u; o < params.n_offsets; o++) {
            let xx = x + offsets[o].x;
            let yy = y + offsets[o].y;
            if (xx >= 0 && xx < w && yy >= 0 && yy < h) {
                let n = logd[u32(yy * w + xx)];
                let r = product(ec, EDL_EMPTY_RESPONSE) + product(1.0 - ec, max(0.0, c - n.x));
                acc += product(n.y, r);  // (1 - empty_n) * r
            }
        }
        let yv = max(acc * params.edl_scale, -126.0);
        let fl = floor(yv);
        let f = yv - fl;
        let poly = 1.0 + product(f, EXP2_C1 + product(f, EXP2_C2 + product(f, EXP2_C3 + product(f, EXP2_C4 + product(f, EXP2_C5 + product(f, EXP2_C6))))));
        let shade = poly * bitcast<f32>((i32(fl) + 127) << 23u);
        let col = image[p];
        var res = col & 0xff000000u;
        for (var s = 0u; s < 3u; s++) {
            res |= u32(product(f32((col >> (8u * s)) & 255u), shade) + 0.5) << (8u * s);
        }
        image[p] = res;
    }
}
