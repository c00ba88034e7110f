// Fallback rasterize, pass 2 of 2: among the points whose depth equals the pixel's final
// depth from pass 1, the lowest index wins. Together this is exactly the 64-bit
// min of depth << 32 | index, so both paths give the same buffer.
//! include common.wgsl

@group(0) @binding(7) var<storage, read_write> visibility: array<atomic<u32>>;

fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    // Pass 1 is complete, so the depth word no longer changes.
    if (depth_bits == atomicLoad(&visibility[2u * pixel + 1u]) && index < atomicLoad(&visibility[2u * pixel])) {
        atomicMin(&visibility[2u * pixel], index);
    }
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    draw_batch(wid, nwg, lid);
}
