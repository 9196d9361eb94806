//! Named extremes of the TFP, TFI and TFSTP luminance conversions, fed by the `represent` kernels
//! the node receives its inputs from: no light, saturating light, one-pixel, one-row and
//! one-column images. Each checks the fast path against the scalar reference as well.

use ndarray::{Array2, Array3, ArrayView2};
use neuspike_representations::{StpFilter, StpParams, isi_into, tfp_into};
use neuspike_schemas::pack_planes;

use crate::{
    luminance_from_isi_into, luminance_from_isi_reference, luminance_from_rate_into,
    luminance_from_rate_reference,
};

/// `(tfp luminance, tfi luminance, isi validity)` of `planes` around the middle plane, each from
/// the fast path after checking it against the reference.
fn both(planes: &Array3<u8>, phi: f64, scale: f64) -> (Array2<f32>, Array2<f32>, Array2<bool>) {
    let (n, h, w) = planes.dim();
    let mut rate = Array2::zeros((h, w));
    tfp_into(planes.view(), rate.view_mut()).expect("tfp");
    let (mut isi, mut valid) = (Array2::zeros((h, w)), Array2::from_elem((h, w), false));
    isi_into(planes.view(), n / 2, isi.view_mut(), valid.view_mut()).expect("isi");
    let lum = |src: ArrayView2<f32>, fast: Fn4, slow: Fn4| {
        let mut a = Array2::from_elem((h, w), f32::NAN);
        let mut b = Array2::from_elem((h, w), f32::NAN);
        fast(src, phi, scale, a.view_mut()).expect("fast");
        slow(src, phi, scale, b.view_mut()).expect("reference");
        assert_eq!(a, b);
        assert!(a.iter().all(|v| (0.0..=1.0).contains(v)), "{a}");
        a
    };
    let tfp = lum(
        rate.view(),
        luminance_from_rate_into,
        luminance_from_rate_reference,
    );
    let tfi = lum(
        isi.view(),
        luminance_from_isi_into,
        luminance_from_isi_reference,
    );
    (tfp, tfi, valid)
}

/// TFSTP's luminance at the middle plane of `planes` (the synapses fed up to it, packed path and
/// reference agreeing), through the TFP conversion as the node does.
fn tfstp(planes: &Array3<u8>, phi: f64, scale: f64) -> Array2<f32> {
    let (n, h, w) = planes.dim();
    let c = n / 2;
    let mut fast = StpFilter::new(h, w, StpParams::default()).expect("stp");
    fast.advance_packed(&pack_planes(planes.view()), 0, n, c as u64)
        .expect("stp");
    let mut reference = StpFilter::new(h, w, StpParams::default()).expect("stp");
    reference
        .advance_reference(planes.slice(ndarray::s![..=c, .., ..]), 0)
        .expect("stp");
    let (mut rate, mut want) = (Array2::zeros((h, w)), Array2::zeros((h, w)));
    fast.rate_into(rate.view_mut()).expect("stp");
    reference.rate_into(want.view_mut()).expect("stp");
    assert_eq!(rate, want);
    let mut lum = Array2::from_elem((h, w), f32::NAN);
    luminance_from_rate_into(rate.view(), phi, scale, lum.view_mut()).expect("lum");
    assert!(lum.iter().all(|v| (0.0..=1.0).contains(v)), "{lum}");
    lum
}

type Fn4 =
    fn(ArrayView2<f32>, f64, f64, ndarray::ArrayViewMut2<f32>) -> Result<(), crate::InferError>;

#[test]
fn no_light_at_all_gives_zero_and_a_finite_bound() {
    let dark = Array3::<u8>::zeros((33, 4, 5));
    let (tfp, tfi, valid) = both(&dark, 1.0, 1.0);
    // Rate 0: luminance exactly 0.
    assert!(tfp.iter().all(|&v| v == 0.0));
    // No spike in the window: the ISI is unknown, its bound N + 1 = 34 gives an upper bound on
    // the luminance, finite, flagged by the mask.
    assert!(tfi.iter().all(|&v| v == (1.0f64 / 34.0) as f32), "{tfi}");
    assert!(valid.iter().all(|&v| !v));
    // No interval ever: TFSTP reads 0.
    assert!(tfstp(&dark, 1.0, 1.0).iter().all(|&v| v == 0.0));
}

#[test]
fn saturating_light_fires_every_tick() {
    let bright = Array3::<u8>::ones((33, 3, 3));
    // phi / light_scale = 0.5: a pixel firing every tick sees luminance 0.5, not clamped.
    let (tfp, tfi, valid) = both(&bright, 1.0, 2.0);
    assert!(tfp.iter().all(|&v| v == 0.5));
    assert!(tfi.iter().all(|&v| v == 0.5));
    assert!(valid.iter().all(|&v| v));
    assert!(tfstp(&bright, 1.0, 2.0).iter().all(|&v| v == 0.5));
    // phi / light_scale = 4: the sensor's ceiling is above the range, clamped to 1.
    let (tfp, tfi, _) = both(&bright, 4.0, 1.0);
    assert!(tfp.iter().chain(&tfi).all(|&v| v == 1.0));
    assert!(tfstp(&bright, 4.0, 1.0).iter().all(|&v| v == 1.0));
}

#[test]
fn one_pixel_image() {
    // Fires every 4th tick: rate 9/33, ISI 4.
    let planes = Array3::from_shape_fn((33, 1, 1), |(k, _, _)| u8::from(k % 4 == 0));
    let (tfp, tfi, valid) = both(&planes, 1.0, 1.0);
    assert!((f64::from(tfp[[0, 0]]) - 9.0 / 33.0).abs() < 1e-7);
    assert_eq!((tfi[[0, 0]], valid[[0, 0]]), (0.25, true));
    assert!((tfstp(&planes, 1.0, 1.0)[[0, 0]] - 0.25).abs() < 1e-6);
}

#[test]
fn one_row_and_one_column_images() {
    for (h, w) in [(1usize, 17usize), (17, 1), (1, 1000)] {
        // Pixel i fires every (i % 5 + 1) ticks.
        let planes = Array3::from_shape_fn((33, h, w), |(k, y, x)| {
            u8::from(k % ((y * w + x) % 5 + 1) == 0)
        });
        let (tfp, tfi, valid) = both(&planes, 1.0, 1.0);
        let stp = tfstp(&planes, 1.0, 1.0);
        for ((y, x), &v) in tfi.indexed_iter() {
            let period = (y * w + x) % 5 + 1;
            assert_eq!(v, (1.0 / period as f64) as f32, "{h}x{w} at ({y}, {x})");
            assert!(
                (stp[[y, x]] - v).abs() < 1e-6,
                "tfstp {h}x{w} at ({y}, {x})"
            );
            assert!(valid[[y, x]]);
            let count = (0..33).filter(|k| k % period == 0).count();
            assert!((f64::from(tfp[[y, x]]) - count as f64 / 33.0).abs() < 1e-7);
        }
    }
}
