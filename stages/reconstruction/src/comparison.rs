//! A measured comparison on simulated scenes (ignored by default; it prints a table):
//!
//! `cargo test --release -p neuspike-reconstruction --lib comparison -- --ignored --nocapture`
//!
//! Both simulators watch the same scene at the same resolution (400x250): the spike camera at
//! 20 kHz (`phi` 1, its default, and 4; its default noise: random initial charge, fixed-pattern ISI
//! cap), the DVS with threshold 0.2 and 3 % mismatch. With `phi = 1` a pixel of luminance 1 fires
//! every tick, so bright pixels have ISIs of 1 or 2 ticks and TFI is coarse; `phi = 4` gives ISIs
//! four times longer and TFP four times fewer spikes. Every `EVAL_STRIDE` planes from plane 100 to 900, each method's
//! luminance at the plane's instant is scored against the ground truth there (PSNR per
//! docs/definitions.md, data range 1, plain and after the least-squares gain):
//!
//! | method | uses |
//! |---|---|
//! | `tfp` | TFP over 33 planes centred on the instant |
//! | `tfi` | the ISI at the instant (65-plane window) |
//! | `tfi_held` | the ISI map of the last anchor (every `ANCHOR_STRIDE` planes), held |
//! | `fusion_*` | Eq. 6-7 from the anchors' ISI maps plus the events up to the instant |
//! | `cf_tfi` | complementary filter: the anchors' TFI frames plus the events |
//! | `hf` | high-pass filter, events only (compare it after gain) |
//!
//! `tfp` and `tfi` see the spikes around every instant; the anchored methods only the spikes around
//! the anchors, and the events in between.

use ndarray::{Array2, Array3, ArrayView2};
use neuspike_event_camera::{DvsConfig, EventCamera};
use neuspike_scene::Scene;
use neuspike_schemas::{bytes_per_plane, unpack_planes_into};
use neuspike_spike_camera::{CameraConfig, SpikeCamera};

use crate::{
    ComplementaryFilter, Contrast, EventSlice, FusionParams, HighPassFilter, PhysicsFusion,
    ThetaMode, luminance_from_isi_into, luminance_from_rate_into,
};

const WIDTH: usize = 400;
const HEIGHT: usize = 250;
const TFP_PLANES: usize = 33;
const ISI_PLANES: usize = 65;
const FIRST: usize = 100;
const LAST: usize = 900;
const EVAL_STRIDE: usize = 10;
const ANCHOR_STRIDE: usize = 100;

/// PSNR (data range 1) and PSNR after the least-squares gain, docs/definitions.md.
fn psnr(x: ArrayView2<f32>, truth: ArrayView2<f32>) -> (f64, f64) {
    let (mut se, mut xg, mut xx) = (0.0f64, 0.0f64, 0.0f64);
    for (&a, &g) in x.iter().zip(truth) {
        let (a, g) = (f64::from(a), f64::from(g));
        se += (a - g) * (a - g);
        xg += a * g;
        xx += a * a;
    }
    let n = x.len() as f64;
    let k = if xx > 0.0 { xg / xx } else { 0.0 };
    let se_gain: f64 = x
        .iter()
        .zip(truth)
        .map(|(&a, &g)| {
            let d = (k * f64::from(a)).clamp(0.0, 1.0) - f64::from(g);
            d * d
        })
        .sum();
    let db = |se: f64| 10.0 * (n / se).log10();
    (db(se), db(se_gain))
}

/// Running means of (plain, after gain) per method, in insertion order.
#[derive(Default)]
struct Table(Vec<(String, f64, f64, usize)>);

impl Table {
    fn add(&mut self, name: &str, x: ArrayView2<f32>, truth: ArrayView2<f32>) {
        let (p, g) = psnr(x, truth);
        match self.0.iter_mut().find(|r| r.0 == name) {
            Some(r) => {
                r.1 += p;
                r.2 += g;
                r.3 += 1;
            }
            None => self.0.push((name.to_owned(), p, g, 1)),
        }
    }

    fn print(&self, title: &str) {
        println!(
            "\n{title}\n| method | PSNR dB | PSNR after gain dB | frames |\n|---|---|---|---|"
        );
        for (name, p, g, n) in &self.0 {
            let k = *n as f64;
            println!("| {name} | {:.2} | {:.2} | {n} |", p / k, g / k);
        }
    }
}

/// Unpacks planes `a..a + n` of the packed stream.
fn planes(bits: &[u8], a: usize, n: usize) -> Array3<u8> {
    let per = bytes_per_plane(WIDTH, HEIGHT);
    let mut dst = Array3::zeros((n, HEIGHT, WIDTH));
    unpack_planes_into(&bits[a * per..(a + n) * per], dst.view_mut());
    dst
}

/// ISI map and validity at plane `k` (window of `ISI_PLANES` centred on it).
fn isi_at(bits: &[u8], k: usize) -> (Array2<f32>, Array2<bool>) {
    let half = ISI_PLANES / 2;
    let p = planes(bits, k - half, ISI_PLANES);
    let (mut isi, mut valid) = (
        Array2::zeros((HEIGHT, WIDTH)),
        Array2::from_elem((HEIGHT, WIDTH), false),
    );
    neuspike_representations::isi_into(p.view(), half, isi.view_mut(), valid.view_mut())
        .expect("isi");
    (isi, valid)
}

fn tfi_of(isi: &Array2<f32>, lum_per_rate: f64) -> Array2<f32> {
    let mut lum = Array2::zeros(isi.dim());
    luminance_from_isi_into(isi.view(), lum_per_rate, 1.0, lum.view_mut()).expect("tfi");
    lum
}

fn compare(scene_name: &str, phi: f64) {
    let scene = Scene::load(scene_name).expect("scene");
    let cfg = CameraConfig {
        width: WIDTH,
        height: HEIGHT,
        phi,
        ..CameraConfig::default()
    };
    let mut spikes = SpikeCamera::new(scene.clone(), cfg).expect("spike camera");
    let lum_per_rate = spikes.lum_per_rate();
    let total = usize::try_from(spikes.total_planes()).expect("planes");
    assert!(total > LAST + ISI_PLANES, "{scene_name}: {total} planes");
    let chunk = spikes.next_chunk(total, 0);
    let bits = &chunk.bits;
    let dvs = DvsConfig {
        width: WIDTH,
        height: HEIGHT,
        ..DvsConfig::default()
    };
    let mut events_cam = EventCamera::new(scene, dvs.clone(), 0).expect("event camera");
    let batch = events_cam.advance_to(spikes.plane_time_ns(total as u64), 0);
    let ev = EventSlice {
        t_ns: &batch.t_ns,
        x: &batch.x,
        y: &batch.y,
        polarity: &batch.polarity,
    };
    println!(
        "\n{scene_name}, phi {phi}: {total} planes of {} ns, {} events ({:.2} per pixel)",
        spikes.period_ns(),
        ev.len(),
        ev.len() as f64 / (WIDTH * HEIGHT) as f64
    );

    let modes = [
        ("fusion_fixed_theta", ThetaMode::Fixed),
        ("fusion_global_theta", ThetaMode::Global),
        ("fusion_per_pixel_theta", ThetaMode::PerPixel),
    ];
    let mut fusions: Vec<PhysicsFusion> = modes
        .iter()
        .map(|&(_, mode)| {
            let p = FusionParams {
                theta_init: dvs.theta_on,
                mode,
                ..FusionParams::new(lum_per_rate, 1.0)
            };
            PhysicsFusion::new(HEIGHT, WIDTH, p, 0).expect("fusion")
        })
        .collect();
    let contrast = Contrast::symmetric(dvs.theta_on);
    let cf_gains = [20.0, 200.0];
    let mut cfs: Vec<ComplementaryFilter> = cf_gains
        .iter()
        .map(|&g| ComplementaryFilter::new(HEIGHT, WIDTH, g, 0).expect("cf"))
        .collect();
    let mut hf = HighPassFilter::new(HEIGHT, WIDTH, 20.0, 0).expect("hf");

    let mut table = Table::default();
    let mut held: Option<Array2<f32>> = None;
    let mut pushed = 0usize;
    let mut push_until = |t_ns: i64,
                          fusions: &mut Vec<PhysicsFusion>,
                          cfs: &mut Vec<ComplementaryFilter>,
                          hf: &mut HighPassFilter| {
        let end = ev.t_ns.partition_point(|&t| t <= t_ns);
        let part = EventSlice {
            t_ns: &ev.t_ns[pushed..end],
            x: &ev.x[pushed..end],
            y: &ev.y[pushed..end],
            polarity: &ev.polarity[pushed..end],
        };
        for f in fusions.iter_mut() {
            f.push_events(part).expect("fusion events");
        }
        for cf in cfs.iter_mut() {
            cf.push_events(part, contrast).expect("cf events");
        }
        hf.push_events(part, contrast).expect("hf events");
        pushed = end;
    };
    let (mut out, mut valid) = (
        Array2::<f32>::zeros((HEIGHT, WIDTH)),
        Array2::from_elem((HEIGHT, WIDTH), false),
    );
    let mut stats = crate::IsiUpdateStats::default();
    let mut clamped = 0usize;
    let first_anchor = FIRST - ANCHOR_STRIDE / 2;
    for k in (first_anchor..=LAST).step_by(EVAL_STRIDE) {
        let t = spikes.plane_time_ns(k as u64);
        push_until(t, &mut fusions, &mut cfs, &mut hf);
        if (k - first_anchor).is_multiple_of(ANCHOR_STRIDE) {
            let (isi, ok) = isi_at(bits, k);
            let tfi = tfi_of(&isi, lum_per_rate);
            for f in fusions.iter_mut() {
                let s = f.push_isi(t, isi.view(), ok.view()).expect("isi");
                if f.params().mode == ThetaMode::PerPixel {
                    stats += s;
                }
            }
            for cf in cfs.iter_mut() {
                cf.push_frame(t, tfi.view()).expect("cf frame");
            }
            held = Some(tfi);
        }
        if k < FIRST {
            continue;
        }
        let truth = spikes.ground_truth(k as u64);
        let half = TFP_PLANES / 2;
        let window = planes(bits, k - half, TFP_PLANES);
        let mut rate = Array2::zeros((HEIGHT, WIDTH));
        neuspike_representations::tfp_into(window.view(), rate.view_mut()).expect("tfp");
        luminance_from_rate_into(rate.view(), lum_per_rate, 1.0, out.view_mut()).expect("tfp");
        table.add("tfp", out.view(), truth.view());
        let (isi, _) = isi_at(bits, k);
        table.add("tfi", tfi_of(&isi, lum_per_rate).view(), truth.view());
        if let Some(h) = &held {
            table.add("tfi_held", h.view(), truth.view());
        }
        for (f, (name, _)) in fusions.iter().zip(&modes) {
            let s = f
                .frame_into(t, out.view_mut(), valid.view_mut())
                .expect("fusion");
            clamped += s.clamped;
            table.add(name, out.view(), truth.view());
        }
        for (cf, g) in cfs.iter().zip(&cf_gains) {
            cf.frame_into(t, out.view_mut()).expect("cf");
            table.add(&format!("cf_tfi_gain_{g}"), out.view(), truth.view());
        }
        hf.frame_into(t, out.view_mut()).expect("hf");
        table.add("hf_cutoff_20", out.view(), truth.view());
    }
    table.print(&format!(
        "{scene_name}, phi {phi}: mean over instants {FIRST}..={LAST} step {EVAL_STRIDE}, anchors every {ANCHOR_STRIDE} planes"
    ));
    let global = fusions[1].theta_global();
    let per_pixel = fusions[2].theta();
    let mean_theta = per_pixel.mean().unwrap_or(f64::NAN);
    let theta_sd = per_pixel.std(0.0);
    println!(
        "theta: true {} (3 % mismatch); pooled estimate {global:?}; per-pixel mean {mean_theta:.4} sd {theta_sd:.4}",
        dvs.theta_on
    );
    println!("per-pixel run: {stats:?}; clamped pixels over all reads {clamped}");
}

#[test]
#[ignore = "simulates two scenes at two thresholds and prints tables (15 s in release)"]
fn comparison_on_simulated_scenes() {
    for name in ["bright-slow", "bright-fast"] {
        for phi in [1.0, 4.0] {
            compare(name, phi);
        }
    }
}
