//! A small complex FFT for the noise generator: radix-2 splits while the length is even, a direct
//! DFT for the odd remainder. Any length works; powers of two are O(n log n).

use std::f64::consts::TAU;

/// A complex number in f64.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Complex {
    pub re: f64,
    pub im: f64,
}

impl Complex {
    pub fn new(re: f64, im: f64) -> Complex {
        Complex { re, im }
    }
    fn add(self, o: Complex) -> Complex {
        Complex::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Complex) -> Complex {
        Complex::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Complex) -> Complex {
        Complex::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
    fn expi(angle: f64) -> Complex {
        Complex::new(angle.cos(), angle.sin())
    }
}

/// Unnormalised DFT with sign `sign` (-1 forward, +1 inverse) of `x`, into a new vector.
pub(crate) fn dft(x: &[Complex], sign: f64) -> Vec<Complex> {
    let n = x.len();
    if n <= 1 {
        return x.to_vec();
    }
    if n % 2 == 1 {
        return (0..n)
            .map(|k| {
                x.iter()
                    .enumerate()
                    .fold(Complex::default(), |acc, (j, &v)| {
                        // (j * k) % n keeps the angle small, so the twiddles stay exact.
                        let angle = sign * TAU * ((j * k) % n) as f64 / n as f64;
                        acc.add(v.mul(Complex::expi(angle)))
                    })
            })
            .collect();
    }
    let even: Vec<Complex> = x.iter().step_by(2).copied().collect();
    let odd: Vec<Complex> = x.iter().skip(1).step_by(2).copied().collect();
    let e = dft(&even, sign);
    let o = dft(&odd, sign);
    let half = n / 2;
    let mut out = vec![Complex::default(); n];
    for k in 0..half {
        let t = Complex::expi(sign * TAU * k as f64 / n as f64).mul(o[k]);
        out[k] = e[k].add(t);
        out[k + half] = e[k].sub(t);
    }
    out
}

/// In-place 2-D DFT of a row-major `rows x cols` grid.
pub(crate) fn dft2(grid: &mut [Complex], rows: usize, cols: usize, sign: f64) {
    debug_assert_eq!(grid.len(), rows * cols);
    for r in 0..rows {
        let row = &mut grid[r * cols..(r + 1) * cols];
        let t = dft(row, sign);
        row.copy_from_slice(&t);
    }
    let mut column = vec![Complex::default(); rows];
    for c in 0..cols {
        for r in 0..rows {
            column[r] = grid[r * cols + c];
        }
        let t = dft(&column, sign);
        for r in 0..rows {
            grid[r * cols + c] = t[r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(x: &[Complex], sign: f64) -> Vec<Complex> {
        let n = x.len();
        (0..n)
            .map(|k| {
                x.iter()
                    .enumerate()
                    .fold(Complex::default(), |acc, (j, &v)| {
                        acc.add(v.mul(Complex::expi(sign * TAU * (j * k) as f64 / n as f64)))
                    })
            })
            .collect()
    }

    #[test]
    fn fft_matches_naive_dft_for_mixed_lengths() {
        for n in [1usize, 2, 3, 4, 6, 8, 12, 15, 16, 18, 20] {
            let x: Vec<Complex> = (0..n)
                .map(|i| Complex::new((i as f64 * 0.7).sin(), (i as f64 * 1.3).cos()))
                .collect();
            let fast = dft(&x, -1.0);
            let slow = naive(&x, -1.0);
            for (a, b) in fast.iter().zip(&slow) {
                assert!(
                    (a.re - b.re).abs() < 1e-9 && (a.im - b.im).abs() < 1e-9,
                    "n={n}"
                );
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
