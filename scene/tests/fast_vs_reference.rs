//! The fast renderer (serial and rayon paths) against the scalar oracle, over random scenes,
//! grids and instants. Tolerance: 1e-5 absolute, relative to the value where a gain map makes
//! values exceed 1.

use ndarray::Array2;
use neuspike_scene::{Scene, render_fast_with, render_reference, render_reference_region};
use proptest::prelude::*;

const KINDS: &[&str] = &["noise", "shapes", "grating", "strokes", "checkerboard"];

fn worst_difference(fast: &Array2<f32>, reference: &Array2<f32>) -> f32 {
    fast.iter()
        .zip(reference.iter())
        .map(|(f, r)| (f - r).abs() / r.abs().max(1.0))
        .fold(0.0f32, f32::max)
}

#[derive(Debug, Clone)]
struct Case {
    yaml: String,
    rows: usize,
    cols: usize,
    t_ns: i64,
}

fn case() -> impl Strategy<Value = Case> {
    (
        (1usize..48, 1usize..48, 1usize..=4, 0usize..KINDS.len(), 8usize..40, any::<u64>()),
        (-3000.0f64..3000.0, -3000.0f64..3000.0, prop_oneof![Just(0.0), -720.0f64..720.0], prop_oneof![Just(0.0), -3.0f64..3.0]),
        (0usize..3, 0.5f64..8.0),
        (1usize..40, 1usize..40),
        prop_oneof![-2_000_000_000i64..2_000_000_000, Just(0i64), Just(i64::MAX), Just(i64::MIN)],
    )
        .prop_map(|((w, h, spp, kind, size, seed), (vx, vy, rot, zoom), (gain, decades), (rows, cols), t_ns)| {
            let gain = match gain {
                0 => String::new(),
                1 => format!("light: {{ gain_map: {{ kind: horizontal, decades: {decades} }} }}\n"),
                _ => format!("light: {{ gain_map: {{ kind: radial, decades: {decades} }} }}\n"),
            };
            let yaml = format!(
                "width: {w}\nheight: {h}\nsamples_per_pixel: {spp}\nseed: {seed}\n\
                 texture: {{ kind: {}, size: {size} }}\n\
                 motion: {{ vx_px_s: {vx}, vy_px_s: {vy}, rotation_deg_s: {rot}, zoom_per_s: {zoom} }}\n{gain}",
                KINDS[kind]
            );
            Case { yaml, rows, cols, t_ns }
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn fast_path_equals_reference(c in case()) {
        let scene = Scene::from_yaml_str(&c.yaml, "proptest", None)
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mut reference = Array2::zeros((c.rows, c.cols));
        render_reference(&scene, c.t_ns, reference.view_mut());
        for parallel in [false, true] {
            let mut fast = Array2::zeros((c.rows, c.cols));
            render_fast_with(&scene, c.t_ns, fast.view_mut(), parallel);
            let worst = worst_difference(&fast, &reference);
            prop_assert!(worst < 1e-5, "parallel={} worst={} case={:?}", parallel, worst, c);
            prop_assert!(fast.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
        // The public entry point picks one of the two.
        prop_assert!(worst_difference(&scene.render(c.t_ns, c.rows, c.cols), &reference) < 1e-5);
    }

    /// A region of the sensor, reaching past its edges, against the oracle's region; where it
    /// lies on the sensor it is the plain render's crop.
    #[test]
    fn a_region_with_a_margin_equals_the_reference(
        c in case(),
        (r0, c0) in (-12i64..12, -12i64..12),
        (extra_r, extra_c) in (0usize..24, 0usize..24),
        (fr, fc) in (0.0f64..1.0, 0.0f64..1.0),
    ) {
        let scene = Scene::from_yaml_str(&c.yaml, "proptest", None)
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let shape = (c.rows + extra_r, c.cols + extra_c);
        let mut reference = Array2::zeros(shape);
        let origin = [r0 as f64, c0 as f64];
        render_reference_region(&scene, c.t_ns, [c.rows, c.cols], origin, reference.view_mut());
        let mut fast = Array2::zeros(shape);
        scene.render_region_into(c.t_ns, [c.rows, c.cols], origin, fast.view_mut());
        prop_assert!(worst_difference(&fast, &reference) < 1e-5, "case={:?}", c);
        // Between the sensor's pixels too.
        let between = [r0 as f64 + fr, c0 as f64 + fc];
        let mut reference_between = Array2::zeros(shape);
        render_reference_region(&scene, c.t_ns, [c.rows, c.cols], between, reference_between.view_mut());
        let mut fast_between = Array2::zeros(shape);
        scene.render_region_into(c.t_ns, [c.rows, c.cols], between, fast_between.view_mut());
        prop_assert!(
            worst_difference(&fast_between, &reference_between) < 1e-5,
            "origin {:?}, case={:?}", between, c
        );
        let whole = scene.render(c.t_ns, c.rows, c.cols);
        for ((i, j), v) in fast.indexed_iter() {
            let (r, cc) = (r0 + i as i64, c0 + j as i64);
            if (0..c.rows as i64).contains(&r) && (0..c.cols as i64).contains(&cc) {
                let w = whole[[r as usize, cc as usize]];
                prop_assert!((v - w).abs() <= 1e-5 * w.abs().max(1.0), "{} vs {}", v, w);
            }
        }
    }
}

#[test]
fn parallel_path_matches_reference_on_a_large_rotating_frame() {
    let scene = Scene::from_yaml_str(
        "samples_per_pixel: 3\ntexture: { kind: noise }\nmotion: { vx_px_s: 777, rotation_deg_s: 33, zoom_per_s: -0.7 }\n\
         light: { gain_map: { kind: radial, decades: 5 } }",
        "large",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mut reference = Array2::zeros((260, 346));
    render_reference(&scene, 31_000_000, reference.view_mut());
    let mut fast = Array2::zeros((260, 346));
    render_fast_with(&scene, 31_000_000, fast.view_mut(), true);
    assert!(worst_difference(&fast, &reference) < 1e-5);
}

/// A mapped render whose map is the plain view's own (pixel to scene by the grid's scale) is the
/// plain render; a map that sends half the frame nowhere leaves it black.
#[test]
fn mapped_render_with_the_views_own_map_is_the_plain_render() {
    let scene = Scene::from_yaml_str(
        "width: 40\nheight: 30\nsamples_per_pixel: 2\ntexture: { kind: noise }\nmotion: { vx_px_s: 300, rotation_deg_s: 20 }\n\
         light: { gain_map: { kind: radial, decades: 2 } }",
        "mapped",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (rows, cols) = (26usize, 35usize);
    let (sx, sy) = (40.0 / cols as f64, 30.0 / rows as f64);
    let mut reference = Array2::zeros((rows, cols));
    render_reference(&scene, 7_000_000, reference.view_mut());
    let mut mapped = Array2::zeros((rows, cols));
    scene.render_mapped_into(7_000_000, &|x, y| Some((x * sx, y * sy)), mapped.view_mut());
    assert!(worst_difference(&mapped, &reference) < 1e-5);
    let mut half = Array2::zeros((rows, cols));
    scene.render_mapped_into(
        7_000_000,
        &|x, y| (x < 10.0).then_some((x * sx, y * sy)),
        half.view_mut(),
    );
    assert!(half.column(20).iter().all(|&v| v == 0.0));
    assert!(
        worst_difference(
            &half.column(3).to_owned().insert_axis(ndarray::Axis(1)),
            &reference.column(3).to_owned().insert_axis(ndarray::Axis(1))
        ) < 1e-5
    );
}
