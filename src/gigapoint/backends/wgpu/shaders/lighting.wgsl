// Blinn-Phong headlight (render/passes/lighting.py; blinn_phong in backends/numba_cpu/pass_kernels.py):
// c * (ambient + diffuse |n.v|) + specular |n.v|^shininess * 255 per channel, from the
// winning point's normal. Normals are paged like colors: one dispatch per page, each
// shading the pixels whose point lies in it, in place on the image.
//! include keys.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> visibility: array<vec2<u32>>;
// This page's normals, 3 floats a point.
@group(0) @binding(2) var<storage, read> normals: array<f32>;
// Unit vectors from each pixel towards the eye, 3 floats a pixel (one for all if one_dir).
@group(0) @binding(3) var<storage, read> view_dirs: array<f32>;
@group(0) @binding(4) var<storage, read_write> image: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let k = visibility[p];
        if (is_empty(k) || k.x < params.page_first || k.x - params.page_first >= params.page_count) {
            continue;
        }
        let i = 3u * (k.x - params.page_first);
        let q = select(3u * p, 0u, params.one_dir != 0u);
        let ndv = min(abs(normals[i] * view_dirs[q] + normals[i + 1u] * view_dirs[q + 1u] + normals[i + 2u] * view_dirs[q + 2u]), 1.0);
        let lit = params.ambient + params.diffuse * ndv;
        // x^y with WGSL's pow is exp2(y log2 x): give 0^y and x^0 the CPU's values
        var pw = 1.0;
        if (params.shininess != 0.0) {
            pw = select(0.0, pow(ndv, params.shininess), ndv > 0.0);
        }
        let spec = params.specular * pw * 255.0;
        let col = image[p];
        var res = col & 0xff000000u;
        for (var s = 0u; s < 3u; s++) {
            let v = f32(channel(col, s)) * lit + spec + 0.5;
            res |= u32(clamp(v, 0.0, 255.0)) << (8u * s);
        }
        image[p] = res;
    }
}
