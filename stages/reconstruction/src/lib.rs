//! Reconstruction of luminance from spike representations, for neuspike's `infer` node.
//!
//! Pure functions, no dora. The spike reconstructions:
//!
//! | [`Method`] | input (from `neuspike-representations`) | luminance |
//! |---|---|---|
//! | `tfp` | firing rate per tick (TFP) | [`luminance_from_rate_into`]: `rate * phi / light_scale` |
//! | `tfi` | inter-spike interval in ticks (ISI) | [`luminance_from_isi_into`]: `phi / (isi * light_scale)` |
//! | `tfstp` | firing rate per tick from short-term plasticity (represent's `stp`) | as `tfp` |
//!
//! and the classical event and spike + event reconstructions, as state machines fed in time order
//! (events, frames or ISI maps pushed, frames read at any later instant):
//!
//! | type | inputs | luminance |
//! |---|---|---|
//! | [`HighPassFilter`] | events | Scheerlinck et al. (ACCV 2018) high-pass filter, `REST_LUMINANCE * exp(L)` |
//! | [`ComplementaryFilter`] | events + spike-camera frames (TFP / TFI luminance) | Scheerlinck et al. complementary filter, `exp(L)` |
//! | [`PhysicsFusion`] | events + ISI maps with their validity | NeuSpike-Net Eq. 5-7: theta from ISI pairs (Eq. 6), `I(t0) exp(theta E)` (Eq. 7) |
//!
//! `phi` is the spike camera's firing threshold and `light_scale` the charge a pixel of luminance 1
//! collects per tick: a pixel of luminance `I` collects `light_scale * I` per tick and fires every
//! `phi / (light_scale * I)` ticks, i.e. at rate `light_scale * I / phi`. Outputs are luminance in
//! `[0, 1]`, clamped, finite everywhere. The learned NeuSpike-Net is [`learned`]: an ONNX file
//! run by tract, its convolutions by neuspike's operators (`neuspike-tract-ops`).
//!
//! [`Online`] runs any [`Method`] window by window, as the `infer` node does; each method
//! declares what it reads ([`Method::inputs`]).
#![deny(missing_docs)]

use std::fmt;
use std::str::FromStr;

use ndarray::{ArrayView2, ArrayViewMut2, Zip};

pub mod auto;
mod filter;
mod fusion;
pub mod learned;
mod online;
pub mod policy;
mod reconstructor;
mod recursive;
mod stage;
#[cfg(test)]
mod testing;

#[cfg(test)]
mod comparison;
#[cfg(test)]
mod extremes;

pub use filter::{
    ComplementaryFilter, Contrast, EVENT_BLOCK, HighPassFilter, LUMINANCE_FLOOR, MAX_CONTRAST,
    REST_LUMINANCE,
};
pub use fusion::{
    FusionFrameStats, FusionParams, IsiUpdateStats, PhysicsFusion, ThetaMode, UnknownThetaMode,
};
/// The events the filters and the fusion take, as `neuspike-representations` defines them.
pub use neuspike_representations::EventSlice;
pub use online::{MethodInputs, Online, OnlineParams, OnlineStats, SpikeInput, Window};
pub use reconstructor::{EVENTS, InferConfig, REPRESENTATION, Reconstructor, WINDOWS};
pub use recursive::{RateFusion, RateFusionParams};
pub use stage::{FRAMES, InferStage};

/// Pixels below which the kernels stay on the calling thread. These maps are memory-bound (tens
/// of microseconds for a 400x250 frame on one core); in a graph every node shares the cores, and
/// waking a thread pool for a frame that small cost milliseconds under load (measured).
pub const MIN_PIXELS_FOR_RAYON: usize = 1 << 22;

/// Why a reconstruction refused its inputs. Messages name the argument and its value.
#[derive(Debug, thiserror::Error)]
pub enum InferError {
    /// A scalar parameter is out of its domain.
    #[error("{name} = {value}: {reason}")]
    Param {
        /// The parameter (or combination, such as `phi / light_scale`).
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it had to satisfy.
        reason: &'static str,
    },
    /// Input and destination images differ in shape.
    #[error("{what}: expected shape {expected:?}, got {actual:?}")]
    Shape {
        /// Which argument.
        what: &'static str,
        /// The input's `[H, W]`.
        expected: [usize; 2],
        /// The destination's `[H, W]`.
        actual: [usize; 2],
    },
    /// An instant earlier than one already pushed: the filters and the fusion run forward in time
    /// only (events, frames and ISI maps are pushed in time order, frames read at or after the
    /// latest of them).
    #[error("{what}: t = {t_ns} ns is before {latest_ns} ns, the latest instant already pushed")]
    TimeBackwards {
        /// What was pushed or asked for.
        what: &'static str,
        /// Its time stamp.
        t_ns: i64,
        /// The latest instant the state has seen.
        latest_ns: i64,
    },
    /// Events that break the invariants of [`EventSlice`] (lengths, time order, polarity ±1,
    /// inside the sensor), as `neuspike-representations` names them.
    #[error("events: {0}")]
    Events(#[from] neuspike_representations::RepresentError),
    /// A window without what its method reads (see [`Method::inputs`]).
    #[error("method `{method}` needs {what}")]
    Missing {
        /// The method.
        method: &'static str,
        /// What it needs, and what came instead.
        what: String,
    },
    /// A method name that is not one of [`Method::ALL`].
    #[error("unknown reconstruction method {value:?}; accepted: {accepted}")]
    UnknownMethod {
        /// The name as given.
        value: String,
        /// The accepted names, comma-separated.
        accepted: &'static str,
    },
    /// The graph does not connect what the method reads, or gives settings it cannot use.
    #[error("{0}")]
    Wiring(String),
    /// A window that cannot be reconstructed, and why.
    #[error("window {seq}: {what}")]
    Window {
        /// The window's sequence number.
        seq: u64,
        /// What is wrong with it.
        what: String,
    },
    /// The learned method was asked to run without its network.
    #[error(
        "method `learned` runs a network: give it `--model FILE` (an ONNX file, e.g. models/neuspike-fused-8.onnx)"
    )]
    NeedsModel,
    /// A learned model that cannot be used: missing, corrupt, or not matching its inputs.
    #[error("model {}: {reason}", path.display())]
    Model {
        /// The ONNX file.
        path: std::path::PathBuf,
        /// What is wrong.
        reason: String,
    },
}

// ---------------------------------------------------------------------------------------------
// Method
// ---------------------------------------------------------------------------------------------

/// A reconstruction method, named as in the graph YAML (`tfp`, `tfi`, `tfstp`, `hf`, `cf`,
/// `fusion`, `learned`, `auto`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Texture from playback: luminance from the firing rate over a window.
    Tfp,
    /// Texture from interval: luminance from the inter-spike interval at the reference plane.
    Tfi,
    /// Texture from short-term plasticity: luminance from the rate that each pixel's synapse
    /// settles at (represent's `stp`, `neuspike_representations::StpFilter`).
    Tfstp,
    /// Events alone: the high-pass filter ([`HighPassFilter`]).
    Hf,
    /// Events with the spike camera's TFP or TFI frames: the complementary filter
    /// ([`ComplementaryFilter`]).
    Cf,
    /// Events with ISI maps: NeuSpike-Net's physics fusion, Eq. 5-7 ([`PhysicsFusion`]); or
    /// events with TFP rates: a recursive log estimate each window's spike count corrects and
    /// the events carry between windows ([`RateFusion`]).
    Fusion,
    /// A NeuSpike-Net exported to ONNX ([`learned::LearnedModel`]), reading the representations
    /// its model names.
    Learned,
    /// Per window, the method the scene needs ([`auto::Auto`]): reads align's windows and
    /// computes only what the chosen method reads.
    Auto,
}

impl Method {
    /// Every method, in the order their names are listed in errors.
    pub const ALL: [Method; 8] = [
        Method::Tfp,
        Method::Tfi,
        Method::Tfstp,
        Method::Hf,
        Method::Cf,
        Method::Fusion,
        Method::Learned,
        Method::Auto,
    ];

    /// The accepted names, as listed in errors.
    const ACCEPTED: &'static str = "tfp, tfi, tfstp, hf, cf, fusion, learned, auto";

    /// The method's name in graph YAML.
    pub fn as_str(&self) -> &'static str {
        match self {
            Method::Tfp => "tfp",
            Method::Tfi => "tfi",
            Method::Tfstp => "tfstp",
            Method::Hf => "hf",
            Method::Cf => "cf",
            Method::Fusion => "fusion",
            Method::Learned => "learned",
            Method::Auto => "auto",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Method {
    type Err = InferError;

    /// Parses the exact lowercase name (`tfp`, `tfi`, `tfstp`, `hf`, `cf`, `fusion`, `learned`); anything
    /// else, other case included, is an [`InferError::UnknownMethod`] naming the value and the
    /// accepted names.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.as_str() == s)
            .ok_or_else(|| InferError::UnknownMethod {
                value: s.to_owned(),
                accepted: Method::ACCEPTED,
            })
    }
}

// ---------------------------------------------------------------------------------------------
// Luminance
// ---------------------------------------------------------------------------------------------

/// Checks `phi` and `light_scale` and returns the gain `phi / light_scale` (finite, `>= 0`).
fn gain(phi: f64, light_scale: f64) -> Result<f64, InferError> {
    for (name, value) in [("phi", phi), ("light_scale", light_scale)] {
        if !(value.is_finite() && value > 0.0) {
            return Err(InferError::Param {
                name,
                value,
                reason: "must be finite and > 0",
            });
        }
    }
    let g = phi / light_scale;
    if !g.is_finite() {
        return Err(InferError::Param {
            name: "phi / light_scale",
            value: g,
            reason: "the gain overflows f64",
        });
    }
    Ok(g)
}

/// Checks that `dst` has the input's shape.
fn check_shape(
    what: &'static str,
    src: (usize, usize),
    dst: (usize, usize),
) -> Result<(), InferError> {
    if src != dst {
        return Err(InferError::Shape {
            what,
            expected: [src.0, src.1],
            actual: [dst.0, dst.1],
        });
    }
    Ok(())
}

/// Clamps to `[0, 1]` with NaN sent to 0, so no NaN or infinity ever leaves a kernel.
#[inline]
fn unit(v: f64) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, 1.0) as f32
    }
}

/// Luminance of one pixel from its rate; the one formula both paths use.
#[inline]
fn from_rate(rate: f32, gain: f64) -> f32 {
    unit(f64::from(rate) * gain)
}

/// Luminance of one pixel from its ISI; the one formula both paths use.
#[inline]
fn from_isi(isi: f32, gain: f64) -> f32 {
    if isi.is_nan() {
        return 0.0;
    }
    unit(gain / f64::from(isi).max(1.0))
}

/// Luminance from a TFP firing rate: `dst = clamp(rate * phi / light_scale, 0, 1)`.
///
/// `rate` is spikes per tick (as `neuspike_representations::tfp_into` writes, in `[0, 1]`). Any `f32` is
/// accepted: negative rates give 0, `+inf` gives 1, NaN gives 0. The product is formed in `f64`.
///
/// # Errors
/// - [`InferError::Param`] when `phi` or `light_scale` is not finite and `> 0` (naming it and its
///   value), or when `phi / light_scale` overflows.
/// - [`InferError::Shape`] when `dst` is not the shape of `rate`.
///
/// ```
/// use ndarray::{array, Array2};
/// let rate = array![[0.25f32, 1.0]];
/// let mut lum = Array2::<f32>::zeros((1, 2));
/// neuspike_reconstruction::luminance_from_rate_into(rate.view(), 1.0, 2.0, lum.view_mut()).unwrap();
/// assert_eq!(lum, array![[0.125f32, 0.5]]);
/// ```
pub fn luminance_from_rate_into(
    rate: ArrayView2<f32>,
    phi: f64,
    light_scale: f64,
    dst: ArrayViewMut2<f32>,
) -> Result<(), InferError> {
    let g = gain(phi, light_scale)?;
    check_shape("luminance dst (shape of rate)", rate.dim(), dst.dim())?;
    let parallel = rate.len() >= MIN_PIXELS_FOR_RAYON;
    map_fast(rate, dst, parallel, |r| from_rate(r, g));
    Ok(())
}

/// Scalar oracle for [`luminance_from_rate_into`].
#[doc(hidden)]
pub fn luminance_from_rate_reference(
    rate: ArrayView2<f32>,
    phi: f64,
    light_scale: f64,
    dst: ArrayViewMut2<f32>,
) -> Result<(), InferError> {
    let g = gain(phi, light_scale)?;
    check_shape("luminance dst (shape of rate)", rate.dim(), dst.dim())?;
    map_reference(rate, dst, |r| from_rate(r, g));
    Ok(())
}

/// Luminance from an inter-spike interval in ticks: `dst = clamp(phi / (isi * light_scale), 0, 1)`.
///
/// `isi` is as `neuspike_representations::isi_into` writes it (`>= 1`; where the ISI was unknown, a lower
/// bound, so the luminance is an upper bound). Any `f32` is accepted: `isi < 1` (zero, negative,
/// `-inf`) is treated as 1, the shortest interval a spike camera can report; `+inf` gives 0; NaN
/// (an interval nobody measured) gives 0.
///
/// # Errors
/// As [`luminance_from_rate_into`].
///
/// ```
/// use ndarray::{array, Array2};
/// let isi = array![[4.0f32, 0.5]];
/// let mut lum = Array2::<f32>::zeros((1, 2));
/// neuspike_reconstruction::luminance_from_isi_into(isi.view(), 1.0, 0.5, lum.view_mut()).unwrap();
/// assert_eq!(lum, array![[0.5f32, 1.0]]);
/// ```
pub fn luminance_from_isi_into(
    isi: ArrayView2<f32>,
    phi: f64,
    light_scale: f64,
    dst: ArrayViewMut2<f32>,
) -> Result<(), InferError> {
    let g = gain(phi, light_scale)?;
    check_shape("luminance dst (shape of isi)", isi.dim(), dst.dim())?;
    let parallel = isi.len() >= MIN_PIXELS_FOR_RAYON;
    map_fast(isi, dst, parallel, |i| from_isi(i, g));
    Ok(())
}

/// Scalar oracle for [`luminance_from_isi_into`].
#[doc(hidden)]
pub fn luminance_from_isi_reference(
    isi: ArrayView2<f32>,
    phi: f64,
    light_scale: f64,
    dst: ArrayViewMut2<f32>,
) -> Result<(), InferError> {
    let g = gain(phi, light_scale)?;
    check_shape("luminance dst (shape of isi)", isi.dim(), dst.dim())?;
    map_reference(isi, dst, |i| from_isi(i, g));
    Ok(())
}

/// Plain indexed loop.
fn map_reference(src: ArrayView2<f32>, mut dst: ArrayViewMut2<f32>, f: impl Fn(f32) -> f32) {
    let (h, w) = src.dim();
    for y in 0..h {
        for x in 0..w {
            dst[[y, x]] = f(src[[y, x]]);
        }
    }
}

/// Element-wise map, layout-aware (`Zip`), on rayon when `parallel`.
fn map_fast(
    src: ArrayView2<f32>,
    dst: ArrayViewMut2<f32>,
    parallel: bool,
    f: impl Fn(f32) -> f32 + Sync + Send,
) {
    let zip = Zip::from(dst).and(src);
    if parallel {
        zip.par_for_each(|d, &s| *d = f(s));
    } else {
        neuspike_simd::dispatch(
            #[inline(always)]
            || zip.for_each(|d, &s| *d = f(s)),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, array};
    use proptest::prelude::*;

    fn rate_lum(rate: &Array2<f32>, phi: f64, s: f64) -> Array2<f32> {
        let mut d = Array2::<f32>::from_elem(rate.dim(), f32::NAN);
        luminance_from_rate_into(rate.view(), phi, s, d.view_mut()).expect("rate");
        d
    }

    fn isi_lum(isi: &Array2<f32>, phi: f64, s: f64) -> Array2<f32> {
        let mut d = Array2::<f32>::from_elem(isi.dim(), f32::NAN);
        luminance_from_isi_into(isi.view(), phi, s, d.view_mut()).expect("isi");
        d
    }

    #[test]
    fn rate_scales_and_clamps() {
        let rate = array![[0.0f32, 0.25, 1.0], [-0.5, f32::NAN, f32::INFINITY]];
        let l = rate_lum(&rate, 2.0, 4.0);
        assert_eq!(l, array![[0.0f32, 0.125, 0.5], [0.0, 0.0, 1.0]]);
        let l = rate_lum(&rate, 8.0, 1.0);
        assert_eq!(l.row(0), array![0.0f32, 1.0, 1.0]);
    }

    #[test]
    fn isi_inverts_clamps_and_floors_at_one_tick() {
        let isi = array![
            [4.0f32, 1.0, 0.5, 0.0],
            [-3.0, f32::INFINITY, f32::NAN, 17.0]
        ];
        let l = isi_lum(&isi, 1.0, 0.5);
        assert_eq!(l.row(0), array![0.5f32, 1.0, 1.0, 1.0]);
        assert_eq!(l.row(1), array![1.0f32, 0.0, 0.0, (2.0f64 / 17.0) as f32]);
    }

    /// Integrate-and-fire pixel of luminance `lum` for `n` ticks: (spike count, last full ISI).
    fn integrate_and_fire(lum: f64, phi: f64, s: f64, n: usize) -> (usize, Option<usize>) {
        let (mut acc, mut count, mut last, mut isi) = (0.0, 0, None::<usize>, None);
        for t in 0..n {
            acc += s * lum;
            if acc >= phi {
                acc -= phi;
                count += 1;
                if let Some(prev) = last {
                    isi = Some(t - prev);
                }
                last = Some(t);
            }
        }
        (count, isi)
    }

    #[test]
    fn simulated_pixel_round_trips_through_rate_and_isi() {
        let (phi, s, n) = (2.0, 1.0, 4_000);
        for lum in [0.05, 0.2, 0.5, 0.9] {
            let (count, isi) = integrate_and_fire(lum, phi, s, n);
            let rate = array![[(count as f64 / n as f64) as f32]];
            let l = f64::from(rate_lum(&rate, phi, s)[[0, 0]]);
            assert!(
                (l - lum).abs() <= phi / (s * n as f64) + 1e-6,
                "lum {lum}: rate gives {l}"
            );
            let isi = isi.expect("fires at least twice") as f32;
            let l = f64::from(isi_lum(&array![[isi]], phi, s)[[0, 0]]);
            // The measured ISI is the true period rounded to a whole tick.
            let period = phi / (s * lum);
            assert!(
                (l - lum).abs() <= lum / (period - 1.0),
                "lum {lum}: isi gives {l}"
            );
        }
    }

    #[test]
    fn bad_parameters_name_the_value() {
        let a = array![[0.5f32]];
        let mut d = Array2::<f32>::zeros((1, 1));
        for (phi, s, needle) in [
            (0.0, 1.0, "phi = 0"),
            (-1.0, 1.0, "phi = -1"),
            (f64::NAN, 1.0, "phi = NaN"),
            (f64::INFINITY, 1.0, "phi = inf"),
            (1.0, 0.0, "light_scale = 0"),
            (1.0, f64::INFINITY, "light_scale = inf"),
            (1e300, 1e-300, "phi / light_scale = inf"),
        ] {
            let e = luminance_from_rate_into(a.view(), phi, s, d.view_mut()).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
            let e = luminance_from_isi_into(a.view(), phi, s, d.view_mut()).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
        }
        let mut wrong = Array2::<f32>::zeros((1, 2));
        let e = luminance_from_rate_into(a.view(), 1.0, 1.0, wrong.view_mut()).expect_err("shape");
        assert!(e.to_string().contains("[1, 2]"), "{e}");
    }

    #[test]
    fn method_names_round_trip_and_errors_list_the_accepted() {
        for m in Method::ALL {
            assert_eq!(m.to_string().parse::<Method>().expect("parse"), m);
        }
        assert_eq!("tfp".parse::<Method>().expect("tfp"), Method::Tfp);
        assert_eq!("tfi".parse::<Method>().expect("tfi"), Method::Tfi);
        use neuspike_schemas::RepresentationKind::{Isi, Stp, Tfp};
        assert_eq!(Method::Tfp.inputs().representations, [Tfp]);
        assert_eq!(Method::Tfi.inputs().representations, [Isi]);
        assert_eq!(Method::Tfstp.inputs().representations, [Stp]);
        assert!(Method::Hf.inputs().events && Method::Hf.inputs().representations.is_empty());
        let e = "TFP".parse::<Method>().expect_err("case");
        assert_eq!(
            e.to_string(),
            "unknown reconstruction method \"TFP\"; accepted: tfp, tfi, tfstp, hf, cf, fusion, learned, auto"
        );
        assert!("".parse::<Method>().is_err());
    }

    #[test]
    fn large_image_takes_the_rayon_path_and_matches() {
        let a = Array2::from_shape_fn((2048, 2048), |(y, x)| (y * 2048 + x) as f32 / 1_000_000.0);
        assert!(a.len() >= MIN_PIXELS_FOR_RAYON);
        let mut fast = Array2::<f32>::zeros(a.dim());
        let mut slow = Array2::<f32>::zeros(a.dim());
        luminance_from_isi_into(a.view(), 3.0, 0.7, fast.view_mut()).expect("fast");
        luminance_from_isi_reference(a.view(), 3.0, 0.7, slow.view_mut()).expect("slow");
        assert_eq!(fast, slow);
        luminance_from_rate_into(a.view(), 3.0, 0.7, fast.view_mut()).expect("fast");
        luminance_from_rate_reference(a.view(), 3.0, 0.7, slow.view_mut()).expect("slow");
        assert_eq!(fast, slow);
    }

    fn image() -> impl Strategy<Value = Array2<f32>> {
        (1usize..8, 1usize..8).prop_flat_map(|(h, w)| {
            proptest::collection::vec(proptest::num::f32::ANY, h * w)
                .prop_map(move |v| Array2::from_shape_vec((h, w), v).expect("shape"))
        })
    }

    proptest! {
        #[test]
        fn fast_equals_reference_and_output_is_unit(
            a in image(), phi in 1e-3f64..1e3, s in 1e-3f64..1e3, par in any::<bool>(), transpose in any::<bool>()
        ) {
            let g = gain(phi, s).expect("gain");
            let src = if transpose { a.t() } else { a.view() };
            let mut slow = Array2::<f32>::zeros(src.dim());
            let mut fast = Array2::<f32>::from_elem(src.dim(), f32::NAN);
            luminance_from_rate_reference(src, phi, s, slow.view_mut()).expect("ref");
            map_fast(src, fast.view_mut(), par, |r| from_rate(r, g));
            prop_assert_eq!(&fast, &slow);
            prop_assert!(fast.iter().all(|v| (0.0..=1.0).contains(v)));
            luminance_from_isi_reference(src, phi, s, slow.view_mut()).expect("ref");
            map_fast(src, fast.view_mut(), par, |i| from_isi(i, g));
            prop_assert_eq!(&fast, &slow);
            prop_assert!(fast.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}
