//! Flags to bits: 64 flags of one byte each packed into one `u64`, flag `j` at bit `j`. A tick of
//! a block of 64 pixels becomes eight bytes of a spike plane this way.
//!
//! The compiler packs such flags with a 64-bit multiply per eight flags, and on AVX-512 it
//! vectorises those multiplies (`vpmullq`, three micro-operations each, on the vector ports the
//! kernel around it needs). One byte-compare into a mask register and one move out of it do the
//! same on AVX-512 BW; AVX2 has `vpmovmskb` for 32 bytes at a time.

use crate::Isa;

/// A way of packing 64 flags into a `u64`: bit `j` is set exactly when `flags[j] != 0`.
///
/// Kernels take one as a type parameter (see [`Packer`]), so the variant compiled for an
/// instruction set holds that set's instructions and no branch.
pub trait Pack64: Copy {
    /// The flags packed, flag `j` at bit `j`.
    fn pack64(self, flags: &[u8; 64]) -> u64;
}

/// [`Pack64`] in plain code, on any CPU.
#[derive(Clone, Copy, Debug)]
pub struct Scalar;

impl Pack64 for Scalar {
    #[inline(always)]
    fn pack64(self, flags: &[u8; 64]) -> u64 {
        pack64_scalar(flags)
    }
}

/// [`Pack64`] with AVX2 (`vpmovmskb`). Made only where the CPU has AVX2 ([`Packer::new`]).
#[derive(Clone, Copy, Debug)]
pub struct Avx2 {
    _checked: (),
}

impl Pack64 for Avx2 {
    #[inline(always)]
    fn pack64(self, flags: &[u8; 64]) -> u64 {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: an `Avx2` exists only where the CPU has AVX2 (see `Packer::new`).
            #[allow(unsafe_code)]
            unsafe {
                x86::avx2(flags)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        pack64_scalar(flags)
    }
}

/// [`Pack64`] with AVX-512 BW (a byte test into a mask register). Made only where the CPU has
/// AVX-512 F, BW and DQ ([`Packer::new`]).
#[derive(Clone, Copy, Debug)]
pub struct Avx512 {
    _checked: (),
}

impl Pack64 for Avx512 {
    #[inline(always)]
    fn pack64(self, flags: &[u8; 64]) -> u64 {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: an `Avx512` exists only where the CPU has AVX-512 BW (see `Packer::new`).
            #[allow(unsafe_code)]
            unsafe {
                x86::avx512(flags)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        pack64_scalar(flags)
    }
}

/// The packer of an instruction set, checked against the CPU. A kernel matches on it and runs
/// each arm through [`crate::with_isa`] with the arm's [`Packer::isa`]:
///
/// ```
/// use neuspike_simd::{Isa, bits::{Pack64, Packer}, with_isa};
/// #[inline(always)]
/// fn kernel<P: Pack64>(p: P, flags: &[u8; 64]) -> u64 { p.pack64(flags) }
/// let flags = [1u8; 64];
/// let packer = Packer::new(Isa::Avx512);
/// let bits = match packer {
///     Packer::Avx512(p) => with_isa(packer.isa(), #[inline(always)] || kernel(p, &flags)),
///     Packer::Avx2(p) => with_isa(packer.isa(), #[inline(always)] || kernel(p, &flags)),
///     Packer::Scalar(p) => with_isa(packer.isa(), #[inline(always)] || kernel(p, &flags)),
/// };
/// assert_eq!(bits, u64::MAX);
/// ```
#[derive(Clone, Copy, Debug)]
pub enum Packer {
    /// Any CPU.
    Scalar(Scalar),
    /// AVX2.
    Avx2(Avx2),
    /// AVX-512 BW.
    Avx512(Avx512),
}

impl Packer {
    /// The packer of `isa` or of the widest instruction set below it this CPU has.
    pub fn new(isa: Isa) -> Packer {
        match isa.min(crate::detect()) {
            Isa::Avx512 => Packer::Avx512(Avx512 { _checked: () }),
            Isa::Avx2 => Packer::Avx2(Avx2 { _checked: () }),
            Isa::Baseline => Packer::Scalar(Scalar),
        }
    }

    /// The instruction set it packs with.
    pub fn isa(self) -> Isa {
        match self {
            Packer::Scalar(_) => Isa::Baseline,
            Packer::Avx2(_) => Isa::Avx2,
            Packer::Avx512(_) => Isa::Avx512,
        }
    }
}

impl Pack64 for Packer {
    /// Packs with the chosen set (a branch per call: for kernels, match on the packer instead).
    #[inline]
    fn pack64(self, flags: &[u8; 64]) -> u64 {
        match self {
            Packer::Scalar(p) => p.pack64(flags),
            Packer::Avx2(p) => p.pack64(flags),
            Packer::Avx512(p) => p.pack64(flags),
        }
    }
}

/// [`Pack64`] as plain code: eight bytes at a time, gathered into one by a multiply.
#[inline(always)]
pub fn pack64_scalar(flags: &[u8; 64]) -> u64 {
    // Byte `j` of a word of 0/1 bytes lands at bit `56 + j` of its product with this constant
    // (no two partial products meet in the top byte).
    const GATHER: u64 = 0x0102_0408_1020_4080;
    let mut bits = 0u64;
    for (i, chunk) in flags.chunks_exact(8).enumerate() {
        let mut eight = [0u8; 8];
        for (e, &f) in eight.iter_mut().zip(chunk) {
            *e = u8::from(f != 0);
        }
        let byte = u64::from_le_bytes(eight).wrapping_mul(GATHER) >> 56;
        bits |= byte << (8 * i);
    }
    bits
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use core::arch::x86_64::*;

    /// One load, one compare into a mask register, one move out.
    #[target_feature(enable = "avx512f,avx512bw")]
    #[inline]
    pub unsafe fn avx512(flags: &[u8; 64]) -> u64 {
        // SAFETY: `flags` holds 64 bytes, one unaligned 512-bit load.
        let v = unsafe { _mm512_loadu_si512(flags.as_ptr().cast()) };
        _mm512_test_epi8_mask(v, v)
    }

    /// Two halves: compare with zero, the bytes' top bits gathered by `vpmovmskb`.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub unsafe fn avx2(flags: &[u8; 64]) -> u64 {
        let zero = _mm256_setzero_si256();
        let half = |k: usize| {
            // SAFETY: bytes `32 k .. 32 k + 32` of the 64, one unaligned 256-bit load.
            let v = unsafe { _mm256_loadu_si256(flags.as_ptr().add(32 * k).cast()) };
            // 0xff where a flag is 0: the mask's complement is the flags.
            let is_zero = _mm256_cmpeq_epi8(v, zero);
            !(_mm256_movemask_epi8(is_zero) as u32)
        };
        u64::from(half(0)) | (u64::from(half(1)) << 32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The plain definition: bit `j` from flag `j`.
    fn reference(flags: &[u8; 64]) -> u64 {
        flags
            .iter()
            .enumerate()
            .fold(0, |b, (j, &f)| b | (u64::from(f != 0) << j))
    }

    #[test]
    fn each_flag_alone_sets_its_own_bit_on_every_isa() {
        for isa in Isa::ALL {
            for j in 0..64 {
                for value in [1u8, 0x80, 0xff] {
                    let mut flags = [0u8; 64];
                    flags[j] = value;
                    assert_eq!(
                        Packer::new(isa).pack64(&flags),
                        1 << j,
                        "{isa:?} flag {j} = {value}"
                    );
                }
            }
            assert_eq!(Packer::new(isa).pack64(&[0; 64]), 0);
            assert_eq!(Packer::new(isa).pack64(&[1; 64]), u64::MAX);
        }
    }

    proptest! {
        #[test]
        fn every_isa_packs_as_the_definition(bytes in proptest::collection::vec(any::<u8>(), 64), sparse in any::<bool>()) {
            let mut flags = [0u8; 64];
            for (f, b) in flags.iter_mut().zip(&bytes) {
                // Mostly 0/1, as kernels give; other values count as set.
                *f = if sparse { b & 1 } else { *b };
            }
            for isa in Isa::ALL {
                prop_assert_eq!(Packer::new(isa).pack64(&flags), reference(&flags), "{:?}", isa);
            }
        }
    }
}
