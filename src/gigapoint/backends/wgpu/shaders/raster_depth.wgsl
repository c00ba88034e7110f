// Fallback rasterize, pass 1 of 2 (no 64-bit atomics): the closest depth per pixel.
// The visibility buffer is bound as u32 pairs; word 2p+1 is the high half of pixel p's
// u64 (depth bits), word 2p the low half (point index), so no pack pass is needed.
//! include common.wgsl

@group(0) @binding(7) var<storage, read_write> visibility: array<atomic<u32>>;

fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    let slot = 2u * pixel + 1u;
    if (depth_bits < atomicLoad(&visibility[slot])) {  // early-depth test
        atomicMin(&visibility[slot], depth_bits);
    }
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    draw_batch(wid, nwg, lid);
}
