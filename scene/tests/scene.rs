//! Behaviour of the scene renderer: determinism, geometry, tiling, ranges, gain maps, errors.

use std::path::PathBuf;

use ndarray::{Array2, s};
use neuspike_scene::{
    GainMapKind, GainMapSpec, LightSpec, Scene, SceneError, SceneSpec, TextureKind, TextureSpec,
    render_reference,
};

fn scene(yaml: &str) -> Scene {
    match Scene::from_yaml_str(yaml, "test.yml", None) {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    }
}

fn error(yaml: &str) -> String {
    match Scene::from_yaml_str(yaml, "graphs/scenes/x.yml", None) {
        Ok(_) => panic!("expected an error for:\n{yaml}"),
        Err(e) => e.to_string(),
    }
}

fn max_abs_diff(a: &Array2<f32>, b: &Array2<f32>) -> f32 {
    a.iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// A unique temporary directory for one test.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("neuspike-scene-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

#[test]
fn same_seed_renders_identically_and_another_seed_differs() {
    for kind in ["noise", "shapes", "strokes"] {
        let yaml = |seed: u64| {
            format!(
                "seed: {seed}\ntexture: {{ kind: {kind}, size: 128 }}\nmotion: {{ vx_px_s: 300 }}"
            )
        };
        let a = scene(&yaml(5)).render(7_000_000, 50, 80);
        let b = scene(&yaml(5)).render(7_000_000, 50, 80);
        let c = scene(&yaml(6)).render(7_000_000, 50, 80);
        assert_eq!(a, b, "{kind}: same seed must render identically");
        assert!(
            max_abs_diff(&a, &c) > 0.1,
            "{kind}: seeds 5 and 6 should give different textures"
        );
    }
}

#[test]
fn still_scene_at_one_sample_per_pixel_equals_the_texels() {
    let s =
        scene("width: 64\nheight: 48\nsamples_per_pixel: 1\ntexture: { kind: noise, size: 64 }");
    let img = s.render(0, 48, 64);
    for r in 0..48 {
        for c in 0..64 {
            assert_eq!(
                img[[r, c]],
                s.texture().texel(r as i64, c as i64),
                "({r}, {c})"
            );
        }
    }
    // Without motion the time does not matter.
    assert_eq!(img, s.render(123_456_789, 48, 64));
}

#[test]
fn still_scene_with_supersampling_averages_the_texture_at_sub_sample_points() {
    let s =
        scene("width: 40\nheight: 30\nsamples_per_pixel: 3\ntexture: { kind: shapes, size: 64 }");
    let img = s.render(0, 30, 40);
    for r in 0..30 {
        for c in 0..40 {
            let mut sum = 0.0;
            for ky in 0..3 {
                for kx in 0..3 {
                    let x = c as f64 + (kx as f64 + 0.5) / 3.0;
                    let y = r as f64 + (ky as f64 + 0.5) / 3.0;
                    sum += s.texture().sample(x, y);
                }
            }
            assert!((img[[r, c]] as f64 - sum / 9.0).abs() < 1e-5, "({r}, {c})");
        }
    }
}

#[test]
fn one_pixel_translation_shifts_the_image_by_one_pixel() {
    // 1000 px/s for 1 ms = 1 px right; -2000 px/s for 0.5 ms = 1 px up.
    let right = scene("texture: { kind: noise }\nmotion: { vx_px_s: 1000 }");
    let a = right.render(0, 250, 400);
    let b = right.render(1_000_000, 250, 400);
    let d = max_abs_diff(
        &b.slice(s![.., 1..]).to_owned(),
        &a.slice(s![.., ..399]).to_owned(),
    );
    assert!(d < 1e-5, "right shift differs by {d}");
    // And it is not trivially equal unshifted.
    assert!(max_abs_diff(&a, &b) > 0.01);

    let up = scene("texture: { kind: strokes }\nmotion: { vy_px_s: -2000 }");
    let a = up.render(0, 250, 400);
    let b = up.render(500_000, 250, 400);
    let d = max_abs_diff(
        &b.slice(s![..249, ..]).to_owned(),
        &a.slice(s![1.., ..]).to_owned(),
    );
    assert!(d < 1e-5, "up shift differs by {d}");
}

#[test]
fn motion_that_starts_late_holds_still_then_moves_from_its_start() {
    // Still until 2 ms, then 1000 px/s: at 3 ms the view is where a scene starting at 0 is at
    // 1 ms.
    let late = scene("texture: { kind: noise }\nmotion: { vx_px_s: 1000, start_ns: 2000000 }");
    let now = scene("texture: { kind: noise }\nmotion: { vx_px_s: 1000 }");
    let still = late.render(0, 250, 400);
    assert_eq!(late.render(2_000_000, 250, 400), still);
    assert_eq!(late.render(-5, 250, 400), still);
    assert_eq!(
        late.render(3_000_000, 250, 400),
        now.render(1_000_000, 250, 400)
    );
    assert!(max_abs_diff(&late.render(3_000_000, 250, 400), &still) > 0.01);
    assert!(!late.is_static());
}

#[test]
fn moving_by_a_texture_period_returns_the_same_image() {
    // Texture period 64 px: 640 px/s for 100 ms and -1280 px/s for 100 ms are whole periods.
    let s = scene(
        "width: 100\nheight: 70\ntexture: { kind: noise, size: 64 }\nmotion: { vx_px_s: 640, vy_px_s: -1280 }",
    );
    let a = s.render(0, 70, 100);
    let b = s.render(100_000_000, 70, 100);
    assert!(max_abs_diff(&a, &b) < 1e-5);
    // The view is wider than the texture: the right part repeats the left part.
    let d = max_abs_diff(
        &a.slice(s![.., 64..]).to_owned(),
        &a.slice(s![.., ..36]).to_owned(),
    );
    assert!(d < 1e-6, "tiling differs by {d}");
    // Half a period is a different image.
    assert!(max_abs_diff(&a, &s.render(50_000_000, 70, 100)) > 0.05);

    // A full turn returns the same image too.
    let turn = scene(
        "width: 80\nheight: 60\ntexture: { kind: grating, size: 64 }\nmotion: { rotation_deg_s: 3600 }",
    );
    let d = max_abs_diff(&turn.render(0, 60, 80), &turn.render(100_000_000, 60, 80));
    assert!(d < 1e-4, "full turn differs by {d}");
}

#[test]
fn values_are_finite_and_within_min_and_one_without_gain_map() {
    for kind in ["noise", "shapes", "grating", "strokes", "checkerboard"] {
        let yaml = format!(
            "texture: {{ kind: {kind}, size: 96, min: 0.05, contrast: 1.7 }}\n\
             motion: {{ vx_px_s: 1234.5, vy_px_s: -77, rotation_deg_s: 45, zoom_per_s: 2.0 }}"
        );
        let s = scene(&yaml);
        for t in [0, 3_000_000, -9_000_000, 1 << 40, i64::MAX, i64::MIN] {
            let img = s.render(t, 60, 90);
            for &v in img.iter() {
                assert!(
                    v.is_finite() && (0.05..=1.0).contains(&v),
                    "{kind} t={t}: {v}"
                );
            }
        }
    }
}

#[test]
fn contrast_zero_gives_a_uniform_mid_grey() {
    let s = scene("texture: { kind: noise, size: 32, contrast: 0.0 }\nmotion: { vx_px_s: 33 }");
    assert!(
        s.render(5_000_000, 20, 30)
            .iter()
            .all(|&v| (v - 0.5).abs() < 1e-6)
    );
}

fn gain_scene(kind: &str, decades: f64) -> Scene {
    scene(&format!(
        "texture: {{ kind: checkerboard, size: 64, contrast: 0.0 }}\n\
         motion: {{ vx_px_s: 500 }}\n\
         light: {{ gain_map: {{ kind: {kind}, decades: {decades} }} }}"
    ))
}

#[test]
fn gain_map_spans_the_requested_decades() {
    for (kind, decades) in [
        ("horizontal", 6.0),
        ("horizontal", 2.5),
        ("radial", 6.0),
        ("radial", 3.0),
    ] {
        let img = gain_scene(kind, decades).render(3_000_000, 250, 400);
        let hi = img.iter().copied().fold(f32::MIN, f32::max) as f64;
        let lo = img.iter().copied().fold(f32::MAX, f32::min) as f64;
        assert!(img.iter().all(|v| v.is_finite() && *v > 0.0));
        let span = (hi / lo).log10();
        assert!(
            (span - decades).abs() < 0.1,
            "{kind} {decades}: span {span} decades"
        );
        // Geometric mean gain 1 on mid-grey: the brightest exceeds 1 by about decades / 2.
        assert!(hi > 1.0, "{kind}: brightest {hi}");
    }
    // Horizontal: brightness increases left to right along every row.
    let img = gain_scene("horizontal", 4.0).render(0, 50, 80);
    for row in img.rows() {
        assert!(row.windows(2).into_iter().all(|w| w[1] > w[0]));
    }
    // Radial: the centre is brighter than the corners.
    let img = gain_scene("radial", 4.0).render(0, 51, 81);
    assert!(img[[25, 40]] > 100.0 * img[[0, 0]]);
}

#[test]
fn any_destination_grid_sees_the_same_view() {
    let s = scene(
        "width: 400\nheight: 250\ntexture: { kind: checkerboard, square_px: 64 }\nsamples_per_pixel: 4",
    );
    // 64 px squares on a 400 x 250 view: the dark/bright pattern at view fractions agrees
    // between a 250 x 400 and a 260 x 346 camera, away from square edges.
    let a = s.render(0, 250, 400);
    let b = s.render(0, 260, 346);
    for (fy, fx) in [
        (0.1, 0.1),
        (0.1, 0.3),
        (0.38, 0.05),
        (0.6, 0.7),
        (0.9, 0.95),
    ] {
        let va = a[[(fy * 250.0) as usize, (fx * 400.0) as usize]];
        let vb = b[[(fy * 260.0) as usize, (fx * 346.0) as usize]];
        assert!(
            (va - vb).abs() < 1e-3,
            "view fraction ({fy}, {fx}): {va} vs {vb}"
        );
    }
}

#[test]
fn non_contiguous_and_degenerate_destinations() {
    let s = Scene::builtin("bright-fast").expect("builtin");
    let contiguous = s.render(12_345_678, 40, 30);
    // Write into a transposed view of a 30 x 40 array: same values.
    let mut storage = Array2::<f32>::zeros((30, 40));
    s.render_into(12_345_678, storage.view_mut().reversed_axes());
    assert_eq!(storage.t(), contiguous);
    // Every other column of a wider array.
    let mut wide = Array2::<f32>::from_elem((40, 60), -1.0);
    s.render_into(12_345_678, wide.slice_mut(s![.., ..;2]));
    assert_eq!(wide.slice(s![.., ..;2]), contiguous);
    assert!(wide.slice(s![.., 1..;2]).iter().all(|&v| v == -1.0));
    // Empty and one-pixel grids.
    assert_eq!(s.render(0, 0, 10).len(), 0);
    assert_eq!(s.render(0, 10, 0).len(), 0);
    let one = s.render(0, 1, 1);
    assert!(one[[0, 0]].is_finite());
}

#[test]
fn fast_path_matches_reference_on_full_size_builtins() {
    for name in Scene::builtin_names() {
        let s = Scene::builtin(name).expect("builtin");
        for t in [0, s.duration_ns() / 3, s.duration_ns()] {
            let fast = s.render(t, 250, 400);
            let mut reference = Array2::zeros((250, 400));
            render_reference(&s, t, reference.view_mut());
            let worst = fast
                .iter()
                .zip(reference.iter())
                .map(|(f, r)| (f - r).abs() / r.abs().max(1.0))
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-5, "{name} t={t}: relative difference {worst}");
        }
    }
}

#[test]
fn max_speed_bounds_the_motion() {
    let s = scene("texture: { kind: noise, size: 32 }\nmotion: { vx_px_s: 30, vy_px_s: -40 }");
    assert!((s.max_speed_px_per_s() - 50.0).abs() < 1e-9);
    let still = scene("texture: { kind: noise, size: 32 }");
    assert_eq!(still.max_speed_px_per_s(), 0.0);
    // Rotation at 90 deg/s: the corner of a 400 x 250 view moves at (pi/2) * 235.8 px/s.
    let r = scene("texture: { kind: noise, size: 32 }\nmotion: { rotation_deg_s: -90 }");
    let corner = 200.0f64.hypot(125.0);
    assert!((r.max_speed_px_per_s() - std::f64::consts::FRAC_PI_2 * corner).abs() < 1e-9);
    // Zooming in grows the translation speed over the duration (50 ms at zoom 2/s).
    let z = scene("texture: { kind: noise, size: 32 }\nmotion: { vx_px_s: 100, zoom_per_s: 2 }");
    let expected = 100.0 * (0.1f64).exp() + 2.0 * corner;
    assert!((z.max_speed_px_per_s() - expected).abs() < 1e-9);
}

#[test]
fn yaml_errors_name_the_field_and_the_value() {
    let e = error("texture: { kind: noise }\ncolour: red");
    assert!(
        e.contains("graphs/scenes/x.yml") && e.contains("colour"),
        "{e}"
    );

    let e = error("texture: { kind: noise, betta: 2 }");
    assert!(e.contains("texture") && e.contains("betta"), "{e}");

    let e = error("texture: { kind: nosie }");
    assert!(
        e.contains("texture.kind") && e.contains("\"nosie\"") && e.contains("checkerboard"),
        "{e}"
    );

    for bad in ["0", "-1.5", ".nan", ".inf"] {
        let e = error(&format!("light_scale: {bad}\ntexture: {{ kind: noise }}"));
        assert!(
            e.contains("field light_scale") && e.contains("must be finite and > 0"),
            "{e}"
        );
    }
    let e = error("light_scale: -1.5\ntexture: { kind: noise }");
    assert!(e.contains("-1.5"), "{e}");

    let e = error("texture: { kind: png, path: no/such/file.png }");
    assert!(
        e.contains("texture.path") && e.contains("no/such/file.png"),
        "{e}"
    );

    let e = error("texture: { kind: png }");
    assert!(e.contains("texture.path") && e.contains("missing"), "{e}");

    let e = error("duration_ms: 5\nduration_ns: 7\ntexture: { kind: noise }");
    assert!(
        e.contains("duration_ms") && e.contains("duration_ns"),
        "{e}"
    );

    let e = error("texture: { kind: grating, beta: 1.0 }");
    assert!(e.contains("texture.beta") && e.contains("grating"), "{e}");

    let e = error("samples_per_pixel: 9\ntexture: { kind: noise }");
    assert!(e.contains("samples_per_pixel") && e.contains('9'), "{e}");

    let e = error("texture: { kind: noise, min: 0 }");
    assert!(e.contains("texture.min") && e.contains('0'), "{e}");

    let e = error("texture: { kind: noise }\nlight: { gain_map: { kind: vertical, decades: 2 } }");
    assert!(
        e.contains("light.gain_map.kind") && e.contains("\"vertical\""),
        "{e}"
    );

    let e = error("texture: { kind: noise }\nlight: { gain_map: { kind: radial, decades: -2 } }");
    assert!(
        e.contains("light.gain_map.decades") && e.contains("-2"),
        "{e}"
    );

    let e = error("width: 0\ntexture: { kind: noise }");
    assert!(e.contains("field width") && e.contains('0'), "{e}");

    let e = error("motion: { vx_px_s: .inf }\ntexture: { kind: noise }");
    assert!(e.contains("motion.vx_px_s") && e.contains("inf"), "{e}");

    let e = error("width: 400");
    assert!(e.contains("texture"), "{e}");

    let e = error("texture: { kind: grating, period_px: 1000 }");
    assert!(e.contains("texture.period_px") && e.contains("1000"), "{e}");

    match Scene::builtin("bright-medium") {
        Err(e @ SceneError::UnknownBuiltin { .. }) => {
            let m = e.to_string();
            assert!(m.contains("bright-medium") && m.contains("hdr-pan"), "{m}");
        }
        other => panic!("expected UnknownBuiltin, got {other:?}"),
    }
    let e = Scene::load("no/such/scene.yml").expect_err("missing file");
    assert!(e.to_string().contains("no/such/scene.yml"), "{e}");
}

#[test]
fn every_builtin_loads_with_its_documented_settings() {
    assert_eq!(
        Scene::builtin_names(),
        &[
            "bright-static",
            "bright-slow",
            "bright-fast",
            "dark-slow",
            "hdr-pan"
        ]
    );
    for name in Scene::builtin_names() {
        let s = Scene::load(name).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((s.width(), s.height()), (400, 250), "{name}");
        assert!(s.duration_ns() > 0);
        let img = s.render(s.duration_ns() / 2, 250, 400);
        assert!(img.iter().all(|v| v.is_finite() && *v > 0.0), "{name}");
    }
    let still = Scene::builtin("bright-static").expect("builtin");
    assert_eq!(still.duration_ns(), 20_000_000);
    assert_eq!(still.max_speed_px_per_s(), 0.0);
    let slow = Scene::builtin("bright-slow").expect("builtin");
    let dark = Scene::builtin("dark-slow").expect("builtin");
    assert_eq!(slow.spec().motion, dark.spec().motion);
    assert_eq!(dark.light_scale(), 0.05);
    // Same texture, only the light differs.
    assert_eq!(
        slow.render(1_000_000, 50, 80),
        dark.render(1_000_000, 50, 80)
    );
    let fast = Scene::builtin("bright-fast").expect("builtin");
    assert!(fast.max_speed_px_per_s() > 2000.0);
    let hdr = Scene::builtin("hdr-pan").expect("builtin");
    let gain = hdr
        .spec()
        .light
        .and_then(|l| l.gain_map)
        .expect("hdr-pan has a gain map");
    assert_eq!(
        gain,
        GainMapSpec {
            kind: GainMapKind::Horizontal,
            decades: 6.0
        }
    );
}

#[test]
fn scene_files_load_by_path_and_resolve_png_next_to_them() {
    let dir = temp_dir("png");
    // An 8-bit RGB gradient and a 16-bit grey image.
    let rgb = image::RgbImage::from_fn(20, 10, |x, _| {
        image::Rgb([(x * 12) as u8, (x * 12) as u8, (x * 12) as u8])
    });
    rgb.save(dir.join("ramp.png")).expect("save png");
    let grey16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(8, 8, |x, y| {
        image::Luma([if (x + y) % 2 == 0 { 65535 } else { 0 }])
    });
    grey16.save(dir.join("checker16.png")).expect("save png");
    let file = dir.join("ramp.yml");
    std::fs::write(
        &file,
        "width: 40\nheight: 10\nsamples_per_pixel: 1\ntexture: { kind: png, path: ramp.png, min: 0.01 }\n",
    )
    .expect("write yaml");
    let s = Scene::load(file.to_str().expect("utf-8 path")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        (s.texture().width(), s.texture().height()),
        (40, 20),
        "mirror-tiled 2W x 2H"
    );
    let img = s.render(0, 10, 40);
    // Left half is the ramp, right half its mirror image.
    for c in 0..20 {
        let expected = ((c * 12) as f32 / 255.0).max(0.01);
        assert!(
            (img[[3, c]] - expected).abs() < 1e-4,
            "col {c}: {}",
            img[[3, c]]
        );
        assert_eq!(img[[3, c]], img[[3, 39 - c]]);
    }

    let grey = Scene::from_yaml_str(
        "width: 8\nheight: 8\nsamples_per_pixel: 1\ntexture: { kind: png, path: checker16.png }",
        "inline",
        Some(&dir),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let img = grey.render(0, 8, 8);
    assert_eq!(img[[0, 0]], 1.0);
    assert_eq!(img[[0, 1]], 0.02);

    // A file that is not a PNG names the field and the path.
    std::fs::write(dir.join("fake.png"), b"not a png").expect("write");
    let e = Scene::from_yaml_str(
        "texture: { kind: png, path: fake.png }",
        "inline",
        Some(&dir),
    )
    .expect_err("not a png");
    assert!(
        e.to_string().contains("texture.path") && e.to_string().contains("fake.png"),
        "{e}"
    );
    // size is not a png parameter.
    let e = Scene::from_yaml_str(
        "texture: { kind: png, path: ramp.png, size: 64 }",
        "inline",
        Some(&dir),
    )
    .expect_err("size on png");
    assert!(e.to_string().contains("texture.size"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn spec_round_trips_through_yaml_and_builds_programmatically() {
    for name in Scene::builtin_names() {
        let s = Scene::builtin(name).expect("builtin");
        let yaml = serde_yaml::to_string(s.spec()).expect("serialize");
        let back = Scene::from_yaml_str(&yaml, "round-trip", None)
            .unwrap_or_else(|e| panic!("{e}\n{yaml}"));
        assert_eq!(back.spec(), s.spec());
    }
    let mut spec = SceneSpec::new(TextureSpec::new(TextureKind::Grating));
    spec.duration_ns = Some(1_000);
    spec.light = Some(LightSpec {
        gain_map: Some(GainMapSpec {
            kind: GainMapKind::Radial,
            decades: 1.0,
        }),
    });
    let s = Scene::from_spec(spec, None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.duration_ns(), 1_000);
    spec = s.spec().clone();
    spec.light_scale = 0.0;
    let e = Scene::from_spec(spec, None).expect_err("light_scale 0");
    assert!(e.to_string().contains("light_scale"), "{e}");
}

/// A noise texture under `motion` (the fields of a scene's `motion:` map).
fn noise_moving(motion: &str) -> Scene {
    Scene::from_yaml_str(
        &format!("texture: {{ kind: noise }}\nmotion: {{ {motion} }}\n"),
        "motion",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

/// The content at the view's centre moves by the motion's translation, turned and scaled as the
/// view is at the later instant; rotation and zoom alone move it not; before the motion starts
/// nothing moves.
#[test]
fn content_shift_follows_the_translation_turned_with_the_view() {
    let scene = noise_moving;
    let close = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9;
    let pan = scene("vx_px_s: 1000, vy_px_s: -500");
    assert!(close(pan.content_shift(0, 2_000_000), (2.0, -1.0)));
    assert!(close(pan.content_shift(2_000_000, 0), (-2.0, 1.0)));
    let turn = scene("rotation_deg_s: 45, zoom_per_s: 0.5");
    assert!(close(turn.content_shift(0, 500_000_000), (0.0, 0.0)));
    // After 1 s of 90 deg/s the view is turned a quarter: x motion shows as y.
    let both = scene("vx_px_s: 1000, rotation_deg_s: 90");
    let (dx, dy) = both.content_shift(1_000_000_000, 1_001_000_000);
    assert!(dx.abs() < 2e-3 && (dy - 1.0).abs() < 1e-3, "{dx} {dy}");
    let late = scene("vx_px_s: 1000, start_ns: 10000000");
    assert!(close(late.content_shift(0, 10_000_000), (0.0, 0.0)));
    assert!(close(late.content_shift(0, 11_000_000), (1.0, 0.0)));
}

/// A motion that stops holds the view where it left it: renders after the stop are the render at
/// the stop, the content's path and shift stop growing, and a stop not after the start is an
/// error naming the field.
#[test]
fn a_motion_that_stops_holds_the_view_where_it_left_it() {
    let scene = noise_moving;
    let s = scene(
        "vx_px_s: 1000, vy_px_s: -500, rotation_deg_s: 30, zoom_per_s: 0.2, start_ns: 1000000, stop_ns: 5000000",
    );
    let free = scene(
        "vx_px_s: 1000, vy_px_s: -500, rotation_deg_s: 30, zoom_per_s: 0.2, start_ns: 1000000",
    );
    // Until the stop, the same motion as one that never stops.
    assert_eq!(s.render(4_000_000, 40, 60), free.render(4_000_000, 40, 60));
    assert_eq!(s.content_path(4_000_000), free.content_path(4_000_000));
    // From the stop on, still.
    let at_stop = s.render(5_000_000, 40, 60);
    assert_ne!(at_stop, s.render(4_000_000, 40, 60));
    assert_eq!(s.render(9_000_000, 40, 60), at_stop);
    assert_eq!(s.content_path(9_000_000), s.content_path(5_000_000));
    assert_eq!(s.content_shift(5_000_000, 9_000_000), (0.0, 0.0));
    let (dx, dy) = s.content_shift(4_000_000, 9_000_000);
    let (ex, ey) = free.content_shift(4_000_000, 5_000_000);
    assert!(
        (dx - ex).abs() < 1e-9 && (dy - ey).abs() < 1e-9,
        "{dx} {dy} vs {ex} {ey}"
    );
    for bad in [
        "start_ns: 2000000, stop_ns: 2000000",
        "start_ns: 2000000, stop_ns: 1000",
    ] {
        let e = Scene::from_yaml_str(
            &format!("texture: {{ kind: noise }}\nmotion: {{ vx_px_s: 10, {bad} }}\n"),
            "stop",
            None,
        )
        .expect_err(bad)
        .to_string();
        assert!(
            e.contains("motion.stop_ns") && e.contains("after motion.start_ns"),
            "{e}"
        );
    }
}

/// The content's path is the integral of the velocity `content_shift` takes at its end: against
/// a fine numerical integral for a pan that turns and zooms (out to where the zoom is held at its
/// clamp), zero before the motion starts, and a plain pan's distance.
#[test]
fn content_path_integrates_the_centres_velocity() {
    let scene = noise_moving;
    let pan = scene("vx_px_s: 1000, vy_px_s: -500, start_ns: 1000000");
    assert_eq!(pan.content_path(0), (0.0, 0.0));
    assert_eq!(pan.content_path(1_000_000), (0.0, 0.0));
    let (x, y) = pan.content_path(3_000_000);
    assert!(
        (x - 2.0).abs() < 1e-12 && (y + 1.0).abs() < 1e-12,
        "{x} {y}"
    );
    // The velocity at `t`: content_shift over a short step ending at `t`, per second.
    let numeric = |s: &Scene, t_end_ns: i64| {
        let step = 10_000i64;
        let (mut x, mut y) = (0.0, 0.0);
        let mut t = 0;
        while t < t_end_ns {
            // The velocity at the step's middle (midpoint rule).
            let mid = t + step / 2;
            let (dx, dy) = s.content_shift(mid - 1, mid);
            x += dx * step as f64;
            y += dy * step as f64;
            t += step;
        }
        (x, y)
    };
    // 60 s of zoom at 0.8/s passes the clamp of 30 in log zoom at 37.5 s.
    for motion in [
        "vx_px_s: 300, vy_px_s: 100, rotation_deg_s: 90, zoom_per_s: 0.5",
        "vx_px_s: -50, rotation_deg_s: -30, zoom_per_s: -0.8",
        "vx_px_s: 2, vy_px_s: 3, rotation_deg_s: 7, zoom_per_s: 0.8",
    ] {
        let s = scene(motion);
        for t in [100_000i64, 1_000_000, 250_000_000, 2_000_000_000] {
            let (a, b) = s.content_path(t);
            let (c, d) = numeric(&s, t);
            let scale = c.hypot(d).max(1.0);
            assert!(
                (a - c).hypot(b - d) < 1e-6 * scale,
                "{motion} at {t} ns: {a} {b} against {c} {d}"
            );
        }
        let far = 60_000_000_000i64;
        let (a, b) = s.content_path(far);
        assert!(a.is_finite() && b.is_finite(), "{motion}: {a} {b}");
    }
    let s = scene("vx_px_s: 2, vy_px_s: 3, rotation_deg_s: 7, zoom_per_s: 0.8");
    // Past the clamp the path goes on at the held zoom: the velocity there times the time.
    let (t1, t2) = (50_000_000_000i64, 50_001_000_000i64);
    let (a, b) = (s.content_path(t1), s.content_path(t2));
    let (vx, vy) = s.content_shift(t2 - 1_000, t2);
    let v = (vx * 1e3, vy * 1e3);
    let step = ((b.0 - a.0) - v.0, (b.1 - a.1) - v.1);
    assert!(
        step.0.hypot(step.1) < 1e-3 * v.0.hypot(v.1),
        "{step:?} against {v:?}"
    );
}

/// Under a pure pan the moved renders follow the content exactly up to the cubic: every image
/// between renders 64 ticks apart against a render at its own instant, at instants a fraction of
/// a pixel apart. Measured 53.0 dB; moving each render by its own fraction of a pixel before
/// blending them gave 45.2 dB, as the two cubics' errors differ and the blend mixes them.
#[test]
fn moved_renders_follow_a_pan_up_to_the_cubic() {
    use neuspike_scene::shift::Interpolator;
    let scene = Scene::from_yaml_str(
        "width: 200\nheight: 120\nduration_ms: 100\nseed: 5\ntexture: { kind: noise, beta: 2.5 }\n\
         motion: { vx_px_s: 1234, vy_px_s: -567, start_ns: 1000000 }\n",
        "pan",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (rows, cols, period) = (120usize, 200usize, 50_000i64);
    let mut warp = Interpolator::new(&scene, rows, cols, -period / 2, 64 * period);
    let mut img = Array2::zeros((rows, cols));
    let (mut worst, mut mse, mut n) = (0.0f32, 0.0f64, 0.0);
    for k in (0..400i64).step_by(3) {
        let t = k * period - period / 2 + 7_919 * (k % 5);
        let truth = scene.render(t, rows, cols);
        warp.image_into(&scene, t, img.view_mut());
        for (a, b) in img.iter().zip(&truth) {
            worst = worst.max((a - b).abs());
            mse += f64::from(a - b).powi(2);
            n += 1.0;
        }
    }
    let psnr = 10.0 * (n / mse).log10();
    eprintln!("pan, renders every 64 ticks: {psnr:.1} dB, worst {worst:.4}");
    assert!(psnr > 50.0, "{psnr} dB");
}

/// Motion-compensated interpolation on `bright-fast` (2,000 px/s while turning 90 deg/s), renders
/// every 64 ticks of 50 us: each tick's image against a render at that tick. Per-tick PSNR of the
/// light: the interpolator above 34 dB; blending the two renders without moving them (linear
/// interpolation in time with the same renders) under 20 dB.
#[test]
fn motion_compensated_images_follow_a_fast_turning_scene() {
    use neuspike_scene::shift::Interpolator;
    let scene = Scene::load("bright-fast").unwrap_or_else(|e| panic!("{e}"));
    let (rows, cols, period) = (250usize, 400usize, 50_000i64);
    let t = |k: u64| k as i64 * period - period / 2;
    let step = 64u64;
    let mut warp = Interpolator::new(&scene, rows, cols, t(0), step as i64 * period);
    assert!(warp.margin() >= 4, "{}", warp.margin());
    let psnr = |mse: f64| 10.0 * (1.0 / mse).log10();
    let (mut warped, mut linear, mut n) = (0.0, 0.0, 0.0);
    let mut img = Array2::zeros((rows, cols));
    for k in (4000u64..4192).step_by(7) {
        let truth = scene.render(t(k), rows, cols);
        warp.image_into(&scene, t(k), img.view_mut());
        warped += (&img - &truth)
            .mapv(|d| f64::from(d).powi(2))
            .mean()
            .unwrap_or(0.0);
        let ka = k - k % step;
        let w = (k - ka) as f32 / step as f32;
        let blend = scene.render(t(ka), rows, cols) * (1.0 - w)
            + scene.render(t(ka + step), rows, cols) * w;
        linear += (&blend - &truth)
            .mapv(|d| f64::from(d).powi(2))
            .mean()
            .unwrap_or(0.0);
        n += 1.0;
    }
    let (warped, linear) = (psnr(warped / n), psnr(linear / n));
    eprintln!(
        "bright-fast, renders every {step} ticks: warped {warped:.1} dB, linear {linear:.1} dB"
    );
    assert!(warped > 34.0, "{warped}");
    assert!(linear < 20.0, "{linear}");
}
