//! The 2-D DFT of the noise generator, through rustfft (any size, `O(n log n)`, its plans made
//! once per call).

use rustfft::{FftDirection, FftPlanner};

/// A complex number in f64.
pub(crate) type Complex = rustfft::num_complex::Complex64;

/// In-place unnormalised 2-D DFT with sign `sign` (negative: forward, `e^{-i..}`; otherwise
/// inverse) of a row-major `rows x cols` grid.
pub(crate) fn dft2(grid: &mut [Complex], rows: usize, cols: usize, sign: f64) {
    if rows == 0 || cols == 0 || grid.len() != rows * cols {
        return;
    }
    let direction = if sign < 0.0 {
        FftDirection::Forward
    } else {
        FftDirection::Inverse
    };
    let mut planner = FftPlanner::new();
    // Rows, all at once; then the columns as the rows of the transpose.
    planner.plan_fft(cols, direction).process(grid);
    let mut t = vec![Complex::default(); rows * cols];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = grid[r * cols + c];
        }
    }
    planner.plan_fft(rows, direction).process(&mut t);
    for c in 0..cols {
        for r in 0..rows {
            grid[r * cols + c] = t[c * rows + r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// The scalar reference: every output of the 2-D sum computed directly.
    fn naive2(x: &[Complex], rows: usize, cols: usize, sign: f64) -> Vec<Complex> {
        let mut out = vec![Complex::default(); rows * cols];
        for (k, o) in out.iter_mut().enumerate() {
            let (kr, kc) = (k / cols, k % cols);
            for (j, v) in x.iter().enumerate() {
                let (jr, jc) = (j / cols, j % cols);
                let angle = sign
                    * TAU
                    * (((jr * kr) % rows) as f64 / rows as f64
                        + ((jc * kc) % cols) as f64 / cols as f64);
                *o += v * Complex::new(angle.cos(), angle.sin());
            }
        }
        out
    }

    #[test]
    fn the_2d_dft_matches_the_direct_sum_for_mixed_sizes() {
        for (rows, cols) in [
            (1usize, 1usize),
            (1, 7),
            (3, 4),
            (6, 8),
            (5, 9),
            (12, 15),
            (16, 16),
        ] {
            let x: Vec<Complex> = (0..rows * cols)
                .map(|i| Complex::new((i as f64 * 0.7).sin(), (i as f64 * 1.3).cos()))
                .collect();
            for sign in [-1.0, 1.0] {
                let mut fast = x.clone();
                dft2(&mut fast, rows, cols, sign);
                let slow = naive2(&x, rows, cols, sign);
                for (a, b) in fast.iter().zip(&slow) {
                    assert!(
                        (a - b).norm() < 1e-9,
                        "{rows}x{cols} sign {sign}: {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn inverse_undoes_forward() {
        let (rows, cols) = (6, 8);
        let orig: Vec<Complex> = (0..rows * cols)
            .map(|i| Complex::new((i as f64).sqrt(), 0.0))
            .collect();
        let mut g = orig.clone();
        dft2(&mut g, rows, cols, -1.0);
        dft2(&mut g, rows, cols, 1.0);
        for (a, b) in g.iter().zip(&orig) {
            assert!((a.re / (rows * cols) as f64 - b.re).abs() < 1e-9);
            assert!((a.im / (rows * cols) as f64).abs() < 1e-9);
        }
    }
}
