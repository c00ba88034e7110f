// Rasterize pass, one 64-bit atomicMin per visible point (adapters with 64-bit atomics).
// The key is depth bits << 32 | point index: the closest point wins, ties go to the lower
// index, whatever order the workgroups run in.
//! include common.wgsl

@group(0) @binding(7) var<storage, read_write> visibility: array<atomic<u64>>;

fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    let key = (u64(depth_bits) << 32u) | u64(index);
    // Early-depth test: a plain load rejects most occluded points without an atomic.
    if (key < atomicLoad(&visibility[pixel])) {
        atomicMin(&visibility[pixel], key);
    }
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    draw_batch(wid, nwg, lid);
}
