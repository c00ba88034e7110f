// Float32 arithmetic as the CPU kernels do it, for passes that must agree with them bit
// for bit. Each including pass declares `params` (layout.PARAMS_DTYPE).

// a * b rounded to float32 before anything is added to it, as the CPU kernels compute it.
// SPIR-V lets a driver fuse a * b + c into one fma (one rounding) unless the result is
// decorated NoContraction, which WGSL cannot ask for. NVIDIA's driver fuses: on an H200,
// 0.6-3 % of a frame's pixels held a depth 1-16 ulps off the CPU's (a different key), none
// once the products were kept. An integer OR with a zero the compiler cannot see
// (params.opaque_zero, always 0) keeps the product a rounded float (~3 % of a raster pass).
fn product(a: f32, b: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(a * b) | params.opaque_zero);
}
