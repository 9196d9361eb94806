//! Run-time choice of the vector instruction set for the kernels of neuspike.
//!
//! Most kernels are written as plain loops without branches over fixed-size blocks, which the
//! compiler vectorises. Compiled for the baseline x86-64 target they get 128-bit vectors; the
//! machines we run on mostly have AVX2 or AVX-512. [`with_isa`] runs a kernel inside a function
//! compiled for the widest instruction set the CPU has (checked once, at run time), so one binary
//! is both portable and fast. The one loop that needs more accumulators than the vectoriser
//! keeps in registers, [`taps::accumulate`] (a convolution's inner loop), is written here with
//! each instruction set's intrinsics, its bounds checked before the loop, and so is its 8-bit
//! counterpart [`dot::accumulate`] (AVX-512 VNNI, where the CPU has it: [`dot::detect`]) and its `bf16`
//! one [`bf16::accumulate`] (AVX-512 BF16: [`bf16::detect`]); so is the loop of
//! loads at computed indices the vectoriser leaves scalar, [`gather::bilinear`] (a renderer's
//! texture samples), its indices clamped inside the image; table lookups by 4-bit indices,
//! [`lut::accumulate`] (a convolution of binary planes, 16 points a permute); and packing 64 flags into a word,
//! [`bits::Pack64`], which the vectoriser does with a multiply per eight flags where AVX-512 has one
//! byte test into a mask register. This crate holds the
//! only `unsafe` of the project: calling a function compiled for an instruction set is sound
//! exactly when the CPU supports it, which is checked right before each call (or when a
//! [`bits::Packer`] is made), and the
//! intrinsics' loads and stores stay within the bounds checked. [`fastmath`] holds the
//! project's branch-free elementary functions (`exp`, `ln`), which vectorise inside such loops.
//! The environment variable `NEUSPIKE_ISA` (`baseline`, `avx2`) makes a wider CPU run the
//! narrower variants, to time them: a loop the compiler leaves scalar for one instruction set
//! shows there and nowhere else.
//!
//! A kernel run through [`with_isa`] must give the same bits on every instruction set; that holds
//! for IEEE add, sub, mul, div, sqrt, min, max and compares (Rust never fuses a multiply and an
//! add unless asked to), and each kernel's tests check it on every [`Isa`] this CPU has. A kernel
//! that wants fused multiply-adds asks with [`f32::mul_add`]: one rounding on every instruction
//! set, one instruction on [`Isa::Avx2`] and [`Isa::Avx512`] (both include FMA), a call to the
//! C library's exact `fmaf` on [`Isa::Baseline`] (slow, but the same bits).
#![deny(missing_docs)]

pub mod bf16;
pub mod bits;
pub mod dot;
pub mod fastmath;
pub mod gather;
pub mod lut;
pub mod taps;

/// The instruction sets kernels can be compiled for, narrowest first (so `a <= b` says that code
/// for `a` runs wherever code for `b` does).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// Whatever the compilation target guarantees (SSE2 on x86-64).
    Baseline,
    /// x86-64 AVX2 and FMA (256-bit vectors; every CPU with AVX2 but a few 2013 VIA parts has
    /// FMA too).
    Avx2,
    /// x86-64 AVX-512 F, BW and DQ (512-bit vectors; AVX-512 F includes FMA; every CPU with BW
    /// has DQ).
    Avx512,
}

impl Isa {
    /// Every instruction set, narrowest first.
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::Avx2, Isa::Avx512];

    /// Lower-case name (`baseline`, `avx2`, `avx512`).
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Whether the kernels here run code compiled for `self`: this CPU supports it and
    /// `NEUSPIKE_ISA` (see [`detect`]) does not name a narrower set.
    pub fn is_supported(self) -> bool {
        self <= detect()
    }
}

/// The environment variable that narrows [`detect`]'s answer: `baseline`, `avx2` or `avx512`.
pub const ISA_VAR: &str = "NEUSPIKE_ISA";

/// The instruction set the kernels run: the widest this CPU supports, or the narrower one
/// [`ISA_VAR`] names, so that a wide CPU can time or test what a narrower one runs. A name wider
/// than the CPU supports leaves the CPU's own; a name that is none of the three is reported once
/// on standard error, in one line, and ignored.
pub fn detect() -> Isa {
    static CAP: std::sync::OnceLock<Option<Isa>> = std::sync::OnceLock::new();
    let cpu = cpu_isa();
    let cap = *CAP.get_or_init(|| {
        let value = std::env::var(ISA_VAR).ok()?;
        let isa = parse_isa(&value);
        if isa.is_none() {
            eprintln!(
                "{ISA_VAR} = {value:?}: not one of baseline, avx2, avx512; running {}",
                cpu.name()
            );
        }
        isa
    });
    cap.map_or(cpu, |c| c.min(cpu))
}

/// An instruction set by its [`Isa::name`] (surrounding spaces and case ignored).
pub fn parse_isa(name: &str) -> Option<Isa> {
    let name = name.trim();
    Isa::ALL
        .into_iter()
        .find(|isa| isa.name().eq_ignore_ascii_case(name))
}

/// The widest instruction set this CPU supports (the standard library caches the CPU query).
fn cpu_isa() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("fma")
        {
            return Isa::Avx512;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Isa::Avx2;
        }
    }
    Isa::Baseline
}

/// Runs `kernel` compiled for the widest instruction set the CPU supports.
#[inline]
pub fn dispatch<R>(kernel: impl FnOnce() -> R) -> R {
    with_isa(detect(), kernel)
}

/// Runs `kernel` compiled for `isa`, or for the widest instruction set below it that the CPU
/// supports (tests and benchmarks use it to compare the variants).
///
/// `kernel` must be a closure marked `#[inline(always)]` that calls `#[inline(always)]` functions
/// (`with_isa(isa, #[inline(always)] || kernel(..))`), so its whole body is compiled inside the
/// variant; without the marks the compiler may keep it out of line, compiled for the baseline.
#[inline]
pub fn with_isa<R>(isa: Isa, kernel: impl FnOnce() -> R) -> R {
    let isa = isa.min(detect());
    #[cfg(target_arch = "x86_64")]
    {
        match isa {
            // SAFETY: `isa <= detect()`: the CPU supports AVX-512 F, BW and DQ.
            #[allow(unsafe_code)]
            Isa::Avx512 => return unsafe { x86::avx512(kernel) },
            // SAFETY: `isa <= detect()`: the CPU supports AVX2 and FMA.
            #[allow(unsafe_code)]
            Isa::Avx2 => return unsafe { x86::avx2(kernel) },
            Isa::Baseline => {}
        }
    }
    let _ = isa;
    kernel()
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn avx2<R>(kernel: impl FnOnce() -> R) -> R {
        kernel()
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512dq,fma")]
    #[inline]
    pub fn avx512<R>(kernel: impl FnOnce() -> R) -> R {
        kernel()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isa_names_parse_back() {
        for isa in Isa::ALL {
            assert_eq!(parse_isa(isa.name()), Some(isa));
        }
        assert_eq!(parse_isa(" AVX2 "), Some(Isa::Avx2));
        assert_eq!(parse_isa("sse9"), None);
        assert_eq!(parse_isa(""), None);
    }

    #[test]
    fn every_isa_runs_and_gives_the_same_bits() {
        let xs: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin()).collect();
        let sum = |xs: &[f32]| {
            let mut acc = [0f32; 16];
            for c in xs.chunks_exact(16) {
                for j in 0..16 {
                    acc[j] += c[j] * c[j] + 0.5;
                }
            }
            acc
        };
        let want = sum(&xs);
        for isa in Isa::ALL {
            assert_eq!(with_isa(isa, || sum(&xs)), want, "{}", isa.name());
        }
        // Fused multiply-adds round once everywhere: not the bits of a multiply then an add.
        let fused = |xs: &[f32]| {
            let mut acc = [0.1f32; 8];
            for c in xs.chunks_exact(8) {
                for j in 0..8 {
                    acc[j] = c[j].mul_add(1.0 / 3.0, acc[j]);
                }
            }
            acc
        };
        let want = fused(&xs);
        for isa in Isa::ALL {
            assert_eq!(with_isa(isa, || fused(&xs)), want, "{}", isa.name());
        }
        assert!(Isa::Baseline.is_supported());
        assert!(detect().is_supported());
    }
}
