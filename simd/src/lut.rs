//! Sums of values looked up in tables of 16 by 4-bit indices, 16 points per instruction: the
//! first convolution of a network reading binary planes.
//!
//! A 3x3 convolution of binary channels adds, for every tap and every input channel whose bit is
//! set, one weight. Four channels' bits at a point make a 4-bit index, and the sum of their
//! weights for one tap and one output channel is one of 16 values, made once per network: a
//! table. The convolution of `4 G` binary channels is then `9 G` table lookups a point and an
//! output channel instead of `36 G` multiply-adds; AVX-512's permute (`vpermps`) looks up 16
//! points in a table of 16 `f32` held in one register. [`accumulate`] adds the lookups of every
//! table to its output in a fixed order, the same on every instruction set.

use crate::Isa;

/// Entries of a table: 4-bit indices.
pub const ENTRIES: usize = 16;

/// Output channels one pass over the points keeps in registers.
const OUTS: usize = 8;

/// For every output `o` and point `j < n`, `out[o][j] += tables[o * T + t][index[t][j] & 15]`
/// for `t = 0, 1, .., T - 1` in that order, one `f32` add at a time (`T = index.len()`), so every
/// instruction set gives the same bits. Only the low 4 bits of an index are read.
///
/// Runs on `isa` or the widest instruction set below it this CPU has.
///
/// # Panics
/// If `tables` does not hold `out.len() * index.len()` tables, or an index or output row is
/// shorter than `n`.
pub fn accumulate(
    isa: Isa,
    tables: &[[f32; ENTRIES]],
    index: &[&[u8]],
    out: &mut [&mut [f32]],
    n: usize,
) {
    assert!(
        tables.len() == out.len() * index.len()
            && index.iter().all(|s| s.len() >= n)
            && out.iter().all(|s| s.len() >= n),
        "{} tables for {} outputs and {} indices, {n} points",
        tables.len(),
        out.len(),
        index.len()
    );
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if isa.min(crate::detect()) == Isa::Avx512 {
        done = 16 * (n / 16);
        // SAFETY: the CPU has AVX-512 F; every load and store is at a point below
        // `16 (n / 16) <= n`, inside the rows checked above, and every table index is
        // `o * T + t` with `o < out.len()` and `t < T`, inside `tables` as checked.
        #[allow(unsafe_code)]
        unsafe {
            x86::avx512(tables, index, out, n / 16)
        }
    }
    let _ = isa;
    let taps = index.len();
    for (o, row) in out.iter_mut().enumerate() {
        let tables = &tables[o * taps..(o + 1) * taps];
        for j in done..n {
            let mut acc = row[j];
            for (table, index) in tables.iter().zip(index) {
                acc += table[usize::from(index[j] & 15)];
            }
            row[j] = acc;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use super::{ENTRIES, OUTS};
    use std::arch::x86_64::*;

    /// The first `16 vectors` points of every output, [`OUTS`] outputs a pass.
    ///
    /// # Safety
    /// The CPU has AVX-512 F; `tables` holds `out.len() * index.len()` tables; every index and
    /// output row holds at least `16 vectors` values.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn avx512(
        tables: &[[f32; ENTRIES]],
        index: &[&[u8]],
        out: &mut [&mut [f32]],
        vectors: usize,
    ) {
        let (mut o0, n_out) = (0, out.len());
        while o0 < n_out {
            let outs = &mut out[o0..(o0 + OUTS).min(n_out)];
            let tables = &tables[o0 * index.len()..];
            // SAFETY: as this function's; `tables` starts at output `o0`'s.
            unsafe {
                match outs.len() {
                    8 => pass::<8, 1>(tables, index, outs, vectors),
                    7 => pass::<7, 1>(tables, index, outs, vectors),
                    6 => pass::<6, 1>(tables, index, outs, vectors),
                    5 => pass::<5, 1>(tables, index, outs, vectors),
                    4 => pass::<4, 2>(tables, index, outs, vectors),
                    3 => pass::<3, 2>(tables, index, outs, vectors),
                    2 => pass::<2, 4>(tables, index, outs, vectors),
                    _ => pass::<1, 4>(tables, index, outs, vectors),
                }
            }
            o0 += OUTS;
        }
    }

    /// `M` outputs (`out.len() == M`), their tables first in `tables`, `P` vectors of points a
    /// step (the sums of one point stay in order; `P` chains of adds hide their latency).
    ///
    /// # Safety
    /// As [`avx512`], for these `M` outputs.
    #[target_feature(enable = "avx512f")]
    unsafe fn pass<const M: usize, const P: usize>(
        tables: &[[f32; ENTRIES]],
        index: &[&[u8]],
        out: &mut [&mut [f32]],
        vectors: usize,
    ) {
        let taps = index.len();
        // SAFETY: loads and stores at points below `16 vectors`, tables below `M * taps`.
        unsafe {
            let mut v = 0;
            while v + P <= vectors {
                let j = 16 * v;
                let mut acc = [[_mm512_setzero_ps(); M]; P];
                for (p, acc) in acc.iter_mut().enumerate() {
                    for (a, row) in acc.iter_mut().zip(out.iter()) {
                        *a = _mm512_loadu_ps(row.as_ptr().add(j + 16 * p));
                    }
                }
                for (t, index) in index.iter().enumerate() {
                    let mut i = [_mm512_setzero_si512(); P];
                    for (p, i) in i.iter_mut().enumerate() {
                        *i = _mm512_cvtepu8_epi32(_mm_loadu_si128(
                            index.as_ptr().add(j + 16 * p).cast(),
                        ));
                    }
                    for o in 0..M {
                        let table = _mm512_loadu_ps(tables.get_unchecked(o * taps + t).as_ptr());
                        for (acc, i) in acc.iter_mut().zip(&i) {
                            acc[o] = _mm512_add_ps(acc[o], _mm512_permutexvar_ps(*i, table));
                        }
                    }
                }
                for (p, acc) in acc.iter().enumerate() {
                    for (a, row) in acc.iter().zip(out.iter_mut()) {
                        _mm512_storeu_ps(row.as_mut_ptr().add(j + 16 * p), *a);
                    }
                }
                v += P;
            }
            if v < vectors {
                // The last vectors, one at a time.
                let (start, rest) = (16 * v, vectors - v);
                let shifted: Vec<&[u8]> = index.iter().map(|s| &s[start..]).collect();
                let mut rows: Vec<&mut [f32]> = out.iter_mut().map(|r| &mut r[start..]).collect();
                pass::<M, 1>(tables, &shifted, &mut rows, rest);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_isa_gives_the_scalar_sums_in_order() {
        let value = |i: usize| ((i * 2_654_435_761) % 1000) as f32 / 997.0 - 0.5;
        for (outs, taps, n) in [(1, 1, 1), (4, 36, 400), (8, 72, 33), (11, 9, 47), (3, 5, 0)] {
            let tables: Vec<[f32; ENTRIES]> = (0..outs * taps)
                .map(|k| std::array::from_fn(|e| value(k * ENTRIES + e)))
                .collect();
            // High bits set in some indices: only the low 4 are read.
            let index: Vec<Vec<u8>> = (0..taps)
                .map(|t| (0..n).map(|j| ((j * 7 + t * 3) % 256) as u8).collect())
                .collect();
            let index: Vec<&[u8]> = index.iter().map(Vec::as_slice).collect();
            let start: Vec<Vec<f32>> = (0..outs)
                .map(|o| (0..n).map(|j| value(o * 31 + j)).collect())
                .collect();
            let want: Vec<Vec<f32>> = (0..outs)
                .map(|o| {
                    (0..n)
                        .map(|j| {
                            let mut acc = start[o][j];
                            for t in 0..taps {
                                acc += tables[o * taps + t][usize::from(index[t][j] % 16)];
                            }
                            acc
                        })
                        .collect()
                })
                .collect();
            for isa in Isa::ALL.into_iter().filter(|i| i.is_supported()) {
                let mut got = start.clone();
                let mut rows: Vec<&mut [f32]> = got.iter_mut().map(Vec::as_mut_slice).collect();
                accumulate(isa, &tables, &index, &mut rows, n);
                assert_eq!(
                    got, want,
                    "{isa:?}: {outs} outputs, {taps} tables, {n} points"
                );
            }
        }
    }

    #[test]
    #[should_panic(expected = "tables for")]
    fn too_few_tables_are_refused() {
        let mut out = vec![0.0f32; 4];
        let index: [&[u8]; 2] = [&[0; 4], &[0; 4]];
        accumulate(Isa::Baseline, &[[0.0; ENTRIES]], &index, &mut [&mut out], 4);
    }
}
