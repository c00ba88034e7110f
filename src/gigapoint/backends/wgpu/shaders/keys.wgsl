// Visibility-buffer keys for the screen-space passes. A u64 key is bound as vec2<u32>
// (little-endian): x = point index (low word), y = float32 depth bits (high word).

const EMPTY_WORD: u32 = 0xffffffffu;

fn is_empty(k: vec2<u32>) -> bool {
    return k.x == EMPTY_WORD && k.y == EMPTY_WORD;
}

// a < b as u64 keys: nearer first, then the lower index.
fn key_less(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.y < b.y || (a.y == b.y && a.x < b.x);
}

// One channel (0 = red .. 3 = alpha) of an RGBA8 color.
fn channel(c: u32, k: u32) -> u32 {
    return (c >> (8u * k)) & 255u;
}
