// Shared by the passes that draw points (rasterize, HQS): the bindings of one page of
// point data, the point decoder, the projection and the splat footprint. The loader inserts this file where a pass says
// `//! include common.wgsl`; the structs BatchRecord and Params are generated from numpy
// dtypes (backends/wgpu/layout.py) and prepended to every shader.

//! include exact.wgsl

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> batches: array<BatchRecord>;
// Struct-of-arrays point words of one page (whole batches), so a 10-bit batch reads
// only `low`: 4 bytes per point instead of 12.
@group(0) @binding(2) var<storage, read> low: array<u32>;
@group(0) @binding(3) var<storage, read> med: array<u32>;
@group(0) @binding(4) var<storage, read> high: array<u32>;
// The same buffer as `low`, seen 4 words at a time for vertex prefetch (paper 3.4).
@group(0) @binding(5) var<storage, read> low4: array<vec4<u32>>;
// Splat footprint (render/splats.py): rows (dx, dy, need, weight) sorted by need;
// weight is the HQS soft-splat weight of the row (-1: computed per point, attenuated sizes).
@group(0) @binding(6) var<storage, read> footprint: array<vec4<i32>>;

// The paper's workgroup: 128 threads share one batch, ~80 points each.
const WORKGROUP_SIZE: u32 = 128u;
const WORD_MASK: u32 = 1023u;
// Exact power of two, so scaling by it never rounds (the CPU kernel relies on the same).
const INV1024: f32 = 0.0009765625;
// A point that lands on no pixel.
const NO_PIXEL: u32 = 0xffffffffu;

// The three 10-bit fields of one packed word, as floats.
fn unpack_word(w: u32) -> vec3<f32> {
    return vec3<f32>(f32(w & WORD_MASK), f32((w >> 10u) & WORD_MASK), f32((w >> 20u) & WORD_MASK));
}

// A point's position in units of its batch's 10-bit grid (cell centres) from its low, medium
// and high words, with the same float32 operations in the same order as grid_coords in
// backends/numba_cpu/raster.py (a 10-bit point: the centre of its grid cell). Medium and high
// words are used only when ``bits`` needs them.
fn grid_coords(low_word: u32, med_word: u32, high_word: u32, bits: u32) -> vec3<f32> {
    let c = unpack_word(low_word);
    if (bits == 10u) {
        return c + 0.5;
    }
    let f = unpack_word(med_word);
    if (bits == 20u) {
        return c + (f + 0.5) * INV1024;
    }
    let g = unpack_word(high_word);
    return c + (f + (g + 0.5) * INV1024) * INV1024;
}

// The compact layout (core/compact.py): where a batch's code is not FULL_LAYOUT, binding 3
// (`med`) holds the page's extension streams (u32 words of the host's u64 words) and a point's
// medium and high words decode from its e_x + e_y + e_z stream bits, step by step as
// read_ext and tail_words in core/compact.py; grid_coords then runs unchanged, so both
// layouts give the same floats.
const FULL_LAYOUT: u32 = 0xffffffffu;

// The e bits at bit pos of the 64-bit value hi:lo (e <= 20).
fn ext_field(lo: u32, hi: u32, pos: u32, e: u32) -> u32 {
    if (e == 0u) {
        return 0u;
    }
    var v = lo;
    if (pos >= 32u) {
        v = hi >> (pos - 32u);
    } else if (pos > 0u) {
        v = (lo >> pos) | (hi << (32u - pos));
    }
    return v & ((1u << e) - 1u);
}

// (medium, high) words of point j of a compact batch whose stream starts at u32 word0.
fn compact_words(word0: u32, code: u32, j: u32) -> vec2<u32> {
    let t = (code & 0xffu) + ((code >> 8u) & 0xffu) + ((code >> 16u) & 0xffu);
    var lo = 0u;
    var hi = 0u;
    if (t > 0u) {
        let p = j * t;
        let w = word0 + (p >> 5u);
        let s = p & 31u;
        let a = med[w];
        let b = med[w + 1u];
        if (s == 0u) {
            lo = a;
            hi = b;
        } else {
            let c = med[w + 2u];
            lo = (a >> s) | (b << (32u - s));
            hi = (b >> s) | (c << (32u - s));
        }
    }
    var words = vec2<u32>(0u, 0u);
    var pos = 0u;
    for (var axis = 0u; axis < 3u; axis++) {
        let e = (code >> (8u * axis)) & 0xffu;
        var tail = ext_field(lo, hi, pos, e) << (20u - e);
        pos += e;
        if (e < 20u) {
            tail |= 1u << (19u - e);
        }
        words.x |= ((tail >> 10u) & WORD_MASK) << (10u * axis);
        words.y |= (tail & WORD_MASK) << (10u * axis);
    }
    return words;
}

// One row of a batch matrix times (p, 1): r.x * p.x + r.y * p.y + r.z * p.z + r.w, left to right.
fn row_dot(r: vec4<f32>, p: vec3<f32>) -> f32 {
    return product(r.x, p.x) + product(r.y, p.y) + product(r.z, p.z) + r.w;
}

// (pixel id or NO_PIXEL, float32 depth bits) of a grid-space point: project_point in raster.py,
// term by term. Depth and w are tested before the divide so no inf/NaN reaches a
// comparison (GPUs need not honour IEEE NaN rules); the CPU kernel rejects the same points.
fn project(m: array<vec4<f32>, 4>, p: vec3<f32>, near: f32, far: f32) -> vec2<u32> {
    let sd = row_dot(m[3], p);
    let sw = row_dot(m[2], p);
    if (!(sd > near && sd < far && sw > 0.0)) {
        return vec2<u32>(NO_PIXEL, 0u);
    }
    let sx = row_dot(m[0], p);
    let sy = row_dot(m[1], p);
    let px = sx / sw;
    let py = sy / sw;
    if (!(px >= 0.0 && px < f32(params.width) && py >= 0.0 && py < f32(params.height))) {
        return vec2<u32>(NO_PIXEL, 0u);
    }
    // depth > near > 0, so its bit pattern orders like the float itself
    return vec2<u32>(u32(py) * params.width + u32(px), bitcast<u32>(sd));
}

// Every pixel a point covers: write_batch in raster.py. A point of size s (params.point_size,
// or with attenuation atten / depth clamped to 1..point_size) covers the footprint rows with
// need <= s, each with the point's own key, so nearer points win pixel by pixel. Each pass
// supplies
//     fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32)
// (WGSL resolves module-scope names in any order), so the loops exist once. ``base``: the
// first pixel of the view's image in the buffer (view v of several: v * width * height).
fn cover(pixel: u32, depth_bits: u32, index: u32, base: u32) {
    if (params.fp_count == 1u) {  // one-pixel points
        visit(base + pixel, depth_bits, index, 0u, 1.0);
        return;
    }
    var s = params.point_size;
    if (params.atten != 0.0) {
        s = min(params.point_size, max(1.0, params.atten / bitcast<f32>(depth_bits)));
    }
    let x = i32(pixel % params.width);
    let y = i32(pixel / params.width);
    for (var o = 0u; o < params.fp_count; o++) {
        let row = footprint[o];
        if (f32(row.z) > s) {
            break;
        }
        let xx = x + row.x;
        let yy = y + row.y;
        if (xx >= 0 && xx < i32(params.width) && yy >= 0 && yy < i32(params.height)) {
            visit(base + u32(yy) * params.width + u32(xx), depth_bits, index, o, s);
        }
    }
}

// One point (index: its global index; words as read) into view v: decoded at the view's
// precision, projected with the view's matrix and clip range, written into the view's image.
fn draw_view(m: array<vec4<f32>, 4>, bits: u32, near: f32, far: f32, v: u32, lw: u32, mw: u32, hw: u32, index: u32) {
    let hit = project(m, grid_coords(lw, mw, hw, bits), near, far);
    if (hit.x != NO_PIXEL) {
        cover(hit.x, hit.y, index, v * params.width * params.height);
    }
}

// Views a draw pipeline writes (stereo: 2), fixed when the pipeline is created: in the
// one-view pipeline every `if (VIEWS > 1u)` block is dead code the driver drops (a views
// loop left to run zero times cost lavapipe about a third of the pass).
override VIEWS: u32 = 1u;

// Matrices and precisions of views 1.. of the batch a thread draws (view 0's: its record).
alias ViewRows = array<array<vec4<f32>, 4>, MAX_VIEWS>;
alias ViewBits = array<u32, MAX_VIEWS>;

// The same point into views 1.. of a multi-view draw (2022 paper, 3.7: read once, drawn into
// every view; the caller draws view 0).
fn draw_other_views(rows: ptr<function, ViewRows>, bits: ptr<function, ViewBits>, lw: u32, mw: u32, hw: u32, index: u32) {
    for (var v = 1u; v < VIEWS; v++) {
        draw_view((*rows)[v], (*bits)[v], params.views[v].x, params.views[v].y, v, lw, mw, hw, index);
    }
}

// One workgroup draws one selected batch, into each of VIEWS views (stereo: two).
fn draw_batch(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) {
    // Dispatches are 2D when there are more batches than one dimension allows (65535).
    let b = wid.x + wid.y * nwg.x;
    if (b >= params.batch_count) {
        return;
    }
    // The batch record first: matrix, precision and point range are the same for all
    // 128 threads (one cached load each).
    let rec = batches[params.batch_offset + b];
    // The words every view needs: the finest precision any view draws the batch at.
    var max_bits = rec.bits;
    // The other views' records, once per thread (not per point). A barrier to share them
    // through workgroup memory would cost CPU drivers (lavapipe: coroutines) more.
    var rows: ViewRows;
    var bits: ViewBits;
    if (VIEWS > 1u) {
        for (var v = 1u; v < VIEWS; v++) {
            let r = batches[params.batch_offset + v * params.batch_count + b];
            rows[v] = r.rows;
            bits[v] = r.bits;
            max_bits = max(max_bits, r.bits);
        }
    }
    // step > 1: every step-th point only (a point budget; Morton order makes it an even subsample)
    let step = max(params.step, 1u);
    let n = (rec.count + step - 1u) / step;
    var tail = 0u;  // first point left to the one-by-one loop
    if (step == 1u && max_bits == 10u && (rec.local_first & 3u) == 0u) {
        // Vertex prefetch (paper 3.4): one 16-byte load yields 4 points' low words;
        // thread t draws points 4t..4t+3, then 4(t+128).. and so on.
        let quads = rec.count / 4u;
        let base = rec.local_first / 4u;
        for (var q = lid; q < quads; q += WORKGROUP_SIZE) {
            let words = low4[base + q];
            for (var k = 0u; k < 4u; k++) {
                let index = rec.first + 4u * q + k;
                draw_view(rec.rows, 10u, params.near, params.far, 0u, words[k], 0u, 0u, index);
                if (VIEWS > 1u) {
                    draw_other_views(&rows, &bits, words[k], 0u, 0u, index);
                }
            }
        }
        tail = 4u * quads;
    }
    // Thread t draws points t, t+128, ...: neighbouring threads read neighbouring words.
    for (var j = tail + lid; j < n; j += WORKGROUP_SIZE) {
        let i = j * step;
        let li = rec.local_first + i;
        var mw = 0u;
        var hw = 0u;
        if (max_bits >= 20u && rec.code != FULL_LAYOUT) {
            let tails = compact_words(rec.ext_first, rec.code, i);
            mw = tails.x;
            hw = tails.y;
        } else {
            if (max_bits >= 20u) {
                mw = med[li];
            }
            if (max_bits >= 30u) {
                hw = high[li];
            }
        }
        let lw = low[li];
        draw_view(rec.rows, rec.bits, params.near, params.far, 0u, lw, mw, hw, rec.first + i);
        if (VIEWS > 1u) {
            draw_other_views(&rows, &bits, lw, mw, hw, rec.first + i);
        }
    }
}
