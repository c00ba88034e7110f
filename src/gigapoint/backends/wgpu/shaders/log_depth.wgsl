// Eye-dome lighting, step 1 (log_depth in backends/numba_cpu/pass_kernels.py): per pixel
// (log2 depth, 1) or (0, 0) where empty, so step 2 computes each logarithm once, not once
// per neighbour. log2 = exponent + atanh series of the mantissa m in [1, 2), from IEEE
// float32 operations in the CPU kernel's order (constants generated from render/params.py;
// products rounded before they are added: exact.wgsl).
//! include keys.wgsl
//! include exact.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> visibility: array<vec2<u32>>;
// x = log2 depth (0 where empty), y = 1 where the pixel holds a point.
@group(0) @binding(2) var<storage, read_write> logd: array<vec2<f32>>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let k = visibility[p];
        if (is_empty(k)) {
            logd[p] = vec2<f32>(0.0, 0.0);
            continue;
        }
        let e = f32(i32(k.y >> 23u) - 127);
        let m = bitcast<f32>((k.y & 0x007fffffu) | 0x3f800000u);
        let t = (m - 1.0) / (m + 1.0);
        let t2 = t * t;
        logd[p] = vec2<f32>(e + product(t, LOG2_C1 + product(t2, LOG2_C3 + product(t2, LOG2_C5 + product(t2, LOG2_C7)))), 1.0);
    }
}
