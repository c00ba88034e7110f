// Transparent points: a point's row of the alpha table, shared by transparency_accumulate and
// transparency_resolve, which each bind `alphas: array<vec4<u32>>` (WGSL resolves module-scope
// names in any order): n rows (first point, 8-bit alpha, revealage term, -) of the selected
// batches, ascending by first point; a point's row is the last whose first is <= its index.

fn alpha_row(index: u32, n: u32) -> vec4<u32> {
    var lo = 0u;
    var hi = n;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (alphas[mid].x <= index) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return alphas[max(lo, 1u) - 1u];
}
