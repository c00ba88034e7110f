// Fill a buffer with params.fill in every u32 (all ones: the empty visibility pixel; zero:
// HQS sums). 16 bytes per store, so CPU drivers (lavapipe) run a quarter of the invocations.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> words: array<vec4<u32>>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    // Grid-stride loop: any frame size with a fixed number of workgroups.
    for (var i = gid.x; i < params.n_items; i += nwg.x * 256u) {
        words[i] = vec4<u32>(params.fill);
    }
}
