//! Test inputs shared by the operators' tests.

/// `n` values in [-1, 1] from a multiplicative hash of the index and `seed`: the kernels' tests'
/// inputs and weights, reproducible and not smooth.
pub(crate) fn pattern(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let k = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8;
            (k % 2001) as f32 / 1000.0 - 1.0
        })
        .collect()
}
