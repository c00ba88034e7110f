// Transparent points, resolve (composite in render/passes/transparency.py; _tr_resolve_rows in
// backends/numba_cpu/pass_kernels.py, step by step in the same integers): the kept fragments
// front to back in 16-bit fixed point, then the tail's mean color for the light they leave
// and the whole pixel does not let through, then the background. Pixels no fragment reached
// keep the color they have (the image holds the fallback colors on entry).
//! include keys.wgsl
//! include transparency_alphas.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> layers: array<vec2<u32>>;
// u64 sums as (low, high) word pairs: 5 per pixel (a, a x r, a x g, a x b, revealage)
@group(0) @binding(2) var<storage, read> sums: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> slot_colors: array<u32>;
@group(0) @binding(4) var<storage, read> alphas: array<vec4<u32>>;
// round(2^16 x 2^(-f / 256)), f = 0..255 (params.transmittance_table)
@group(0) @binding(5) var<storage, read> transmittance: array<u32>;
@group(0) @binding(6) var<storage, read_write> image: array<u32>;

const FULL: u32 = 65536u;

fn to64(v: vec2<u32>) -> u64 {
    return u64(v.x) | (u64(v.y) << 32u);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    for (var p = gid.x; p < params.n_items; p += nwg.x * 256u) {
        let reveal = to64(sums[5u * p + 4u]);
        if (reveal == 0lu) {
            continue;
        }
        var t = FULL;
        var acc = vec3<u32>(0u);
        var kept_a = 0lu;
        var kept = vec3<u64>(0lu);
        for (var i = 0u; i < TR_LAYERS; i++) {
            let key = layers[p * TR_LAYERS + i];
            if (is_empty(key)) {
                break;
            }
            let a = alpha_row(key.x, params.n_offsets).y;
            let c = slot_colors[p * TR_LAYERS + i];
            let rgb = vec3<u32>(c & 255u, (c >> 8u) & 255u, (c >> 16u) & 255u);
            let w = (a * t + 127u) / 255u;
            acc += w * rgb;
            t -= w;
            kept_a += u64(a);
            kept += vec3<u64>(u64(a * rgb.x), u64(a * rgb.y), u64(a * rgb.z));
        }
        let tail_a = to64(sums[5u * p]) - kept_a;
        if (tail_a > 0lu) {
            let lg = reveal >> TR_COUNT_BITS;
            let e = lg >> TR_REVEAL_BITS;
            var t_all = 0u;
            if (e < 16lu) {
                t_all = transmittance[u32((lg >> (TR_REVEAL_BITS - 8u)) & 255lu)] >> u32(e);
            }
            t_all = min(t_all, t);
            var s = 0u;
            while ((tail_a >> s) >= 65536lu) {
                s += 1u;
            }
            let w16 = u32(tail_a >> s);
            let h = w16 >> 1u;
            let tw = t - t_all;
            let r = u32((to64(sums[5u * p + 1u]) - kept.x) >> s);
            let g = u32((to64(sums[5u * p + 2u]) - kept.y) >> s);
            let b = u32((to64(sums[5u * p + 3u]) - kept.z) >> s);
            acc += tw * vec3<u32>((r + h) / w16, (g + h) / w16, (b + h) / w16);
            t = t_all;
        }
        let bg = params.background;
        let out = (acc + vec3<u32>(bg & 255u, (bg >> 8u) & 255u, (bg >> 16u) & 255u) * t + 32768u) >> vec3<u32>(16u);
        let alpha = (255u * (FULL - t) + (bg >> 24u) * t + 32768u) >> 16u;
        image[p] = out.x | (out.y << 8u) | (out.z << 16u) | (alpha << 24u);
    }
}
