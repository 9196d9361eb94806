//! End-to-end: whole graphs on the embedded dora daemon, from simulated cameras to scored PNGs.
//!
//! The graphs' `build:` commands build the node binaries first (release profile, as the graphs
//! name `target/release`), so this test works on a fresh clone.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

/// One row of the sink's metrics.csv.
#[derive(Debug)]
struct Row {
    method: String,
    seq: u64,
    psnr_db: Option<f64>,
    ssim: Option<f64>,
    file: String,
}

fn read_metrics(dir: &Path) -> Vec<Row> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).expect("metrics.csv written");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("column {name}"))
    };
    let (m, s, p, ss, f) = (
        col("method"),
        col("seq"),
        col("psnr_db"),
        col("ssim"),
        col("file"),
    );
    lines
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let num = |i: usize| -> Option<f64> {
                match v[i] {
                    "" => None,
                    "inf" => Some(f64::INFINITY),
                    x => Some(x.parse().expect("number")),
                }
            };
            Row {
                method: v[m].to_string(),
                seq: v[s].parse().expect("seq"),
                psnr_db: num(p),
                ssim: num(ss),
                file: v[f].to_string(),
            }
        })
        .collect()
}

/// Groups the metrics by method, checks that every method wrote frames `0..n` (the same `n`
/// for all), each scored with a finite PSNR, and returns `n` and the methods' mean PSNR and SSIM.
fn per_method_means(rows: &[Row]) -> (usize, BTreeMap<&str, f64>, BTreeMap<&str, f64>) {
    let mut per_method: BTreeMap<&str, Vec<&Row>> = BTreeMap::new();
    for r in rows {
        per_method.entry(r.method.as_str()).or_default().push(r);
    }
    let n = per_method.values().next().map_or(0, Vec::len);
    let (mut psnr, mut ssim) = (BTreeMap::new(), BTreeMap::new());
    for (m, rows) in &per_method {
        let seqs: Vec<u64> = rows.iter().map(|r| r.seq).collect();
        assert_eq!(seqs, (0..n as u64).collect::<Vec<_>>(), "method {m}");
        let p: Vec<f64> = rows.iter().map(|r| r.psnr_db.expect("scored")).collect();
        assert!(p.iter().all(|p| p.is_finite()), "method {m}: {p:?}");
        psnr.insert(*m, p.iter().sum::<f64>() / p.len() as f64);
        let s: f64 = rows.iter().map(|r| r.ssim.expect("ssim")).sum();
        ssim.insert(*m, s / rows.len() as f64);
    }
    (n, psnr, ssim)
}

fn graph(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("graphs")
        .join(name)
}

/// One whole graph at a time: each is a dozen processes, and ten of them at once on two cores
/// starve one another.
static ONE_GRAPH: Mutex<()> = Mutex::new(());

fn one_graph() -> MutexGuard<'static, ()> {
    // A test that failed while holding it poisons nothing the next one needs.
    ONE_GRAPH.lock().unwrap_or_else(|e| e.into_inner())
}

fn run(name: &str, out: &Path, extra: &[(&str, &str)]) {
    let _one = one_graph();
    let mut overrides = vec![("sink".to_string(), format!("--out {}", out.display()))];
    overrides.extend(extra.iter().map(|(n, a)| (n.to_string(), a.to_string())));
    let report = neuspike::graph::run(
        &graph(name),
        &overrides,
        true,
        Some(Duration::from_secs(300)),
        None,
    )
    .expect("graph ran");
    assert!(report.failures.is_empty(), "{:?}", report.failures);
}

/// The PNGs under `dir`, by path relative to it, with their bytes.
fn pngs(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    for sub in std::fs::read_dir(dir).expect("out folder").flatten() {
        if !sub.path().is_dir() {
            continue;
        }
        for f in std::fs::read_dir(sub.path())
            .expect("method folder")
            .flatten()
        {
            if f.path().extension().is_some_and(|x| x == "png") {
                let name = format!(
                    "{}/{}",
                    sub.file_name().to_string_lossy(),
                    f.file_name().to_string_lossy()
                );
                out.insert(name, std::fs::read(f.path()).expect("png"));
            }
        }
    }
    out
}

/// SHA-256 of the demo's frames: every PNG `graphs/demo.yml` writes, as [`frames_digest`] reads
/// them. The frames of `neuspike demo` stay these, byte for byte, whatever the code around them
/// becomes; a change that moves them has to say why here.
const DEMO_FRAMES_SHA256: &str = "f43271d6fe54e0de0fe37da3101c2964922f4c5520b81426561569f2cf77fb1c";

/// SHA-256 over the frames in `dir` (as [`pngs`] finds them), in name order: each name, a zero
/// byte, the file's length as 8 little-endian bytes, then its bytes.
fn frames_digest(dir: &Path) -> (usize, String) {
    use sha2::Digest;
    let frames = pngs(dir);
    let mut hash = sha2::Sha256::new();
    for (name, bytes) in &frames {
        hash.update(name.as_bytes());
        hash.update([0u8]);
        hash.update((bytes.len() as u64).to_le_bytes());
        hash.update(bytes);
    }
    let hex = hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
    (frames.len(), hex)
}

/// The demo's frames are the recorded ones ([`DEMO_FRAMES_SHA256`]), computed by the program on
/// every instruction set this CPU has (`NEUSPIKE_ISA`): the fast kernels and the scalar ones give
/// the same frames, and so does every machine.
#[test]
fn the_demo_frames_are_the_recorded_ones_on_every_instruction_set() {
    for isa in neuspike_simd::Isa::ALL {
        if !isa.is_supported() {
            continue;
        }
        let out = tempfile::tempdir().expect("tempdir");
        let run = {
            let _one = one_graph();
            std::process::Command::new(env!("CARGO_BIN_EXE_neuspike"))
                .arg("run")
                .arg("--in-process")
                .arg(graph("demo.yml"))
                .arg("--set")
                .arg(format!("sink=--out {}", out.path().display()))
                .env(neuspike_simd::ISA_VAR, isa.name())
                .output()
                .expect("neuspike run")
        };
        assert!(
            run.status.success(),
            "{}: {}",
            isa.name(),
            String::from_utf8_lossy(&run.stderr)
        );
        let (frames, digest) = frames_digest(out.path());
        assert!(frames >= 80, "{}: {frames} frames", isa.name());
        assert_eq!(
            digest,
            DEMO_FRAMES_SHA256,
            "{}: the demo's {frames} frames changed",
            isa.name()
        );
    }
}

/// The demo graph under dora (its processes as it ships) and in process (one chain of the same
/// stages, no dora) writes the same frames, byte for byte, and loses nothing either way: the stages are
/// one code path whichever driver runs them.
#[test]
fn the_demo_graph_in_process_writes_the_frames_dora_writes() {
    let by_dora = tempfile::tempdir().expect("tempdir");
    run("demo.yml", by_dora.path(), &[]);
    let in_process = tempfile::tempdir().expect("tempdir");
    let (_, chain) = {
        let _one = one_graph();
        let sink = format!("--out {}", in_process.path().display());
        neuspike::in_process::run(&graph("demo.yml"), &[("sink".to_string(), sink)])
            .expect("in process")
    };
    neuspike::in_process::check(&chain).expect("nothing lost in process");
    let (a, b) = (pngs(by_dora.path()), pngs(in_process.path()));
    let names = |m: &BTreeMap<String, Vec<u8>>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&a), names(&b));
    for method in ["tfp/", "tfi/"] {
        let n = a.keys().filter(|k| k.starts_with(method)).count();
        assert!(n >= 40, "{method}: {n} frames");
    }
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs");
    }
    let sink = chain.stage("sink").expect("sink");
    for input in ["tfp", "tfi"] {
        let t = sink.inputs.get(input).expect("input");
        let written = b.keys().filter(|k| k.starts_with(input)).count() as u64;
        assert_eq!(
            (t.received, t.missing, t.cut),
            (written, 0, false),
            "{input}"
        );
    }
}

/// The demo graph with its stages in other processes than it ships with (`processes:`): a
/// process a stage; then every stage, both cameras and the sink included, in one (the cameras
/// and the sink on threads of their own). Both write the frames the in-process chain writes,
/// byte for byte, and lose nothing.
#[test]
fn the_demo_graph_fused_into_processes_writes_the_same_frames() {
    let reference = tempfile::tempdir().expect("tempdir");
    let (_, chain) = {
        let _one = one_graph();
        let sink = format!("--out {}", reference.path().display());
        neuspike::in_process::run(&graph("demo.yml"), &[("sink".to_string(), sink)])
            .expect("in process")
    };
    neuspike::in_process::check(&chain).expect("nothing lost in process");
    let want = pngs(reference.path());
    assert!(want.len() >= 80, "{} frames", want.len());
    let mut demo: serde_yaml::Value =
        serde_yaml::from_str(&std::fs::read_to_string(graph("demo.yml")).expect("demo.yml"))
            .expect("yaml");
    for processes in [
        "{}",
        "{all: [spike-source, event-source, align, represent, infer-tfp, infer-tfi, sink]}",
    ] {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("fused.yml");
        demo["processes"] = serde_yaml::from_str(processes).expect("processes");
        std::fs::write(&path, serde_yaml::to_string(&demo).expect("yaml")).expect("write");
        let out = dir.path().join("out");
        let report = {
            let _one = one_graph();
            let sink = vec![("sink".to_string(), format!("--out {}", out.display()))];
            neuspike::graph::run(&path, &sink, true, Some(Duration::from_secs(300)), None)
                .expect("graph ran")
        };
        assert!(
            report.failures.is_empty(),
            "{processes}: {:?}",
            report.failures
        );
        assert!(
            report.losses().is_empty(),
            "{processes}: {:?}",
            report.losses()
        );
        let got = pngs(&out);
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            want.keys().collect::<Vec<_>>(),
            "{processes}"
        );
        for (name, bytes) in &want {
            assert!(got[name] == *bytes, "{processes}: {name} differs");
        }
    }
}

/// The demo graph written out whole by `neuspike graph` (credit edges, message types) runs under
/// the stock dora CLI (`dora run`) with nothing lost.
#[test]
fn a_written_out_graph_runs_lossless_under_the_stock_dora_cli() {
    let has_dora = std::process::Command::new("dora")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_dora {
        eprintln!("notice: skipped: no dora CLI (pip install dora-rs-cli==1.1.0)");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let written = dir.path().join("demo.yml");
    let _one = one_graph();
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_neuspike"))
        .arg("graph")
        .arg(graph("demo.yml"))
        .arg("--set")
        .arg(format!("sink=--out {}", out.display()))
        .arg("--out")
        .arg(&written)
        .status()
        .expect("neuspike graph");
    assert!(status.success());
    // The nodes are built already: the written graph's `build:` keys are for a user's first run.
    let mut g: serde_yaml::Value =
        serde_yaml::from_str(&std::fs::read_to_string(&written).expect("read")).expect("yaml");
    for n in g["nodes"].as_sequence_mut().expect("nodes") {
        n.as_mapping_mut().expect("node").remove("build");
    }
    std::fs::write(&written, serde_yaml::to_string(&g).expect("yaml")).expect("write");
    let run = std::process::Command::new("dora")
        .arg("run")
        .arg(&written)
        .current_dir(dir.path())
        .output()
        .expect("dora run");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let summary: neuspike_sink::report::SummaryFile = serde_yaml::from_str(
        &std::fs::read_to_string(out.join("summary.yml")).expect("summary.yml"),
    )
    .expect("summary");
    for input in ["tfp", "tfi", "ground_truth"] {
        let c = &summary.inputs[input].counts;
        assert!(c.ended && !c.cut && c.missing == 0, "{input}: {c:?}");
        assert_eq!(c.received, c.expected, "{input}");
        assert!(c.expected >= 49, "{input}: {c:?}");
    }
}

/// Static bright scene, spike camera only: every window becomes a TFP frame, nothing is lost,
/// and the reconstruction is close to the truth (a broken pipeline — wrong scale, flipped rows,
/// shifted clock — cannot reach the floor).
#[test]
fn spike_tfp_static_scene_is_complete_and_accurate() {
    let out = tempfile::tempdir().expect("tempdir");
    run("spike-tfp.yml", out.path(), &[]);
    let rows = read_metrics(out.path());
    // bright-static: 20 ms at 20 kHz = 400 planes; 33-plane windows every 20 planes centred on
    // multiples of 20 from 20 to 380: 19 frames.
    let tfp: Vec<&Row> = rows.iter().filter(|r| r.method == "tfp").collect();
    assert_eq!(tfp.len(), 19, "frames written: {rows:?}");
    let seqs: Vec<u64> = tfp.iter().map(|r| r.seq).collect();
    assert_eq!(seqs, (0..19).collect::<Vec<_>>());
    for r in &tfp {
        assert!(out.path().join(&r.file).is_file(), "{} missing", r.file);
        let p = r.psnr_db.expect("every frame has ground truth");
        assert!(p > 25.0, "frame {} PSNR {p:.2} dB", r.seq);
        assert!(
            r.ssim.expect("ssim") > 0.7,
            "frame {} SSIM {:?}",
            r.seq,
            r.ssim
        );
    }
    let summary = std::fs::read_to_string(out.path().join("summary.md")).expect("summary");
    assert!(summary.contains("tfp"), "{summary}");
}

/// A sink much slower than its camera holds the whole graph back through the credits: nothing
/// is lost and nothing queues up. Were the producers not held, frame `k` would wait behind `k`
/// others (latency growing to seconds); held, it waits behind at most the frames the credits let
/// into the graph.
#[test]
fn a_slow_sink_holds_the_graph_back_without_loss_or_queues() {
    let out = tempfile::tempdir().expect("tempdir");
    let delay_ms = 20;
    run(
        "spike-tfp-live.yml",
        out.path(),
        &[
            ("spike-source", "--max-planes 4020 --scene bright-static"),
            (
                "sink",
                &format!("--delay-us {} --write-every 50", delay_ms * 1000),
            ),
        ],
    );
    let text = std::fs::read_to_string(out.path().join("summary.yml")).expect("summary.yml");
    let summary: neuspike_sink::report::SummaryFile = serde_yaml::from_str(&text).expect("summary");
    let tfp = &summary.inputs["tfp"];
    assert_eq!(
        (tfp.counts.expected, tfp.counts.received, tfp.counts.missing),
        (200, 200, 0),
        "{text}"
    );
    assert_eq!(tfp.counts.written, 4, "seq 0, 50, 100, 150: {text}");
    let latency = tfp.latency.expect("frames carry their origin");
    // 4 links of 8 credits: about 32 frames ahead of the sink at most, 20 ms each; unheld, the
    // last of the 200 frames would wait about 4 s.
    let bound_ms = 60.0 * delay_ms as f64;
    assert!(
        latency.max_ms < bound_ms,
        "latency grew to {:.0} ms (bound {bound_ms} ms): the producers were not held",
        latency.max_ms
    );
    // And the sink did wait: the frames behind it waited too.
    assert!(latency.p50_ms > delay_ms as f64, "{latency:?}");
}

/// Both cameras, TFP and TFI: both methods produce every frame and nothing goes missing.
#[test]
fn demo_graph_both_cameras_loses_nothing() {
    let out = tempfile::tempdir().expect("tempdir");
    run("demo.yml", out.path(), &[]);
    let rows = read_metrics(out.path());
    let mut per_method: BTreeMap<&str, Vec<u64>> = BTreeMap::new();
    for r in &rows {
        per_method.entry(r.method.as_str()).or_default().push(r.seq);
    }
    assert_eq!(
        per_method.keys().copied().collect::<Vec<_>>(),
        vec!["tfi", "tfp"]
    );
    let n = per_method["tfp"].len();
    assert!(n >= 40, "only {n} frames");
    for (m, seqs) in &per_method {
        assert_eq!(*seqs, (0..n as u64).collect::<Vec<_>>(), "method {m}");
    }
    assert!(
        rows.iter().all(|r| r.psnr_db.is_some()),
        "every frame scored"
    );
}

/// Every classical reconstruction on both cameras (`graphs/fusion.yml`): each of the six methods
/// produces every frame, nothing is lost, every frame is scored, and the figures hold their
/// measured order on the bright panning scene (TFP far ahead; TFSTP's synapses well above the
/// single interval of TFI; the fusion at least TFI, whose ISI it anchors on). The event filters' structure is checked by SSIM: a flat image at the
/// filters' rest level scores about 0.15 here (HF's first frame, before any event, does), and
/// HF measured 0.42, so a broken event path (wrong clock, lost batches, flipped polarity)
/// falls under the 0.3 floor. PSNR cannot tell: the flat image has 16.4 dB, HF 15.8.
#[test]
fn fusion_graph_runs_every_method_and_loses_nothing() {
    let out = tempfile::tempdir().expect("tempdir");
    run("fusion.yml", out.path(), &[]);
    let rows = read_metrics(out.path());
    let (n, psnr, ssim) = per_method_means(&rows);
    assert_eq!(
        psnr.keys().copied().collect::<Vec<_>>(),
        vec!["cf", "fusion", "hf", "tfi", "tfp", "tfstp"]
    );
    assert!(n >= 40, "only {n} frames");
    assert!(psnr["tfp"] > 30.0, "{psnr:?}");
    assert!(psnr["fusion"] >= psnr["tfi"] - 0.1, "{psnr:?}");
    assert!(psnr["tfstp"] > psnr["tfi"] + 3.0, "{psnr:?}");
    for m in ["hf", "cf", "fusion", "tfi"] {
        assert!(ssim[m] > 0.3, "{m}: {ssim:?}");
    }
}

/// The same graph on a rig of two sensors (`graphs/fusion.yml` with its event camera at
/// 346x260, seeing the view through a homography, its clock 3 ms ahead; align given both): every
/// method still gives every frame, and the event methods still resemble the truth. Each spike
/// pixel takes the events of the DVS pixel its centre falls in (SSIM here: hf 0.40, cf 0.45,
/// fusion 0.51; on one grid hf 0.42).
#[test]
fn fusion_graph_runs_on_a_rig_of_two_sensor_sizes_and_clocks() {
    let out = tempfile::tempdir().expect("tempdir");
    // 346x260 over the 400x250 view, turned by half a degree.
    let h = common::davis346_rig();
    let dvs = format!(
        "--scene bright-slow --width 346 --height 260 --batch-ns 1000000 --seed 2 --homography {h} --clock-offset-ns 3000000"
    );
    let align = format!(
        "--window-planes 33 --stride-planes 20 --homography {h} --event-offset-ns -3000000"
    );
    run(
        "fusion.yml",
        out.path(),
        &[("event-source", dvs.as_str()), ("align", align.as_str())],
    );
    let rows = read_metrics(out.path());
    let (n, psnr, ssim) = per_method_means(&rows);
    assert_eq!(
        psnr.keys().copied().collect::<Vec<_>>(),
        vec!["cf", "fusion", "hf", "tfi", "tfp", "tfstp"]
    );
    assert!(n >= 40, "only {n} frames");
    eprintln!("rig: PSNR {psnr:?}, SSIM {ssim:?}");
    assert!(psnr["fusion"] >= psnr["tfi"] - 0.5, "{psnr:?}");
    for m in ["hf", "cf", "fusion"] {
        assert!(ssim[m] > 0.33, "{m}: {ssim:?}");
    }
}

/// `neuspike simulate` of `scene` into `dir/rec`: 600 planes, both cameras 400x250 on one clock
/// (the DVS's thresholds `theta`), ground truth every 20 planes.
fn paired_recording(dir: &Path, scene: &str, theta: f64) -> PathBuf {
    let rec = dir.join("rec");
    let dvs = neuspike_event_camera::DvsConfig {
        width: 400,
        height: 250,
        theta_on: theta,
        theta_off: theta,
        ..Default::default()
    };
    neuspike::record::simulate(&neuspike::record::SimulateOptions {
        scene: scene.into(),
        out: rec.clone(),
        planes: Some(600),
        gt_every_planes: 20,
        chunk_planes: 200,
        events: true,
        spike: Default::default(),
        dvs,
        progress: false,
    })
    .expect("simulate");
    rec
}

/// A paired recording from `neuspike simulate` (both cameras 400x250, on one clock, ground truth
/// every 20 planes), played back by `neuspike reconstruct --events` for each method that reads
/// events, the learned fused network included (`--method learned --model`): every window becomes
/// a frame, nothing is lost, the recorded ground truth (found beside the spike file, or for `cf`
/// its copy as APS frames in the AEDAT 4 file) scores every frame, and the frames resemble it (the
/// SSIM floor of the simulated graph's test).
#[test]
fn reconstruct_plays_a_paired_recording_through_the_event_methods() {
    use neuspike::reconstruct::{Method, ReconstructOptions, reconstruct};
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = paired_recording(dir.path(), "bright-slow", 0.2);
    let fused = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/neuspike-fused-8.onnx");
    // Two of the methods play the events from the AEDAT 4 copy, two from the EVT 2.0 one; one
    // is scored against the truth's copy as APS frames in the AEDAT 4 file (as a DAVIS's frames
    // would be), the others against the PNG folder.
    for (method, model, events, truth) in [
        (Method::Hf, None, "events.raw", None),
        (
            Method::Cf,
            None,
            "events.aedat4",
            Some(rec.join("events.aedat4")),
        ),
        (Method::Fusion, None, "events.raw", None),
        (Method::Learned, Some(fused), "events.aedat4", None),
    ] {
        let out = dir.path().join(format!("{method:?}"));
        let opts = ReconstructOptions {
            spikes: rec.join("spikes.dat"),
            events: Some(rec.join(events)),
            truth,
            method,
            model,
            policy: Path::new(env!("CARGO_MANIFEST_DIR")).join("models/policy.yml"),
            out: out.clone(),
            source_args: String::new(),
            event_source_args: String::new(),
            infer_args: String::new(),
            window_planes: Some(33),
            stride_planes: 20,
            bit_depth: 8,
            build: true,
        };
        let report = reconstruct(&opts).expect("reconstruct ran");
        assert!(
            report.failures.is_empty(),
            "{method:?}: {:?}",
            report.failures
        );
        let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary");
        // (600 - 33) / 20 + 1 windows, each a frame, none missing; 30 truth frames.
        let name = format!("{method:?}").to_lowercase();
        assert!(
            summary.contains(&format!("| {name} | 29 | 29 | 29 | 0 | yes |")),
            "{method:?}: {summary}"
        );
        assert!(
            summary.contains("| ground_truth | 30 | 30 | 30 | 0 | yes |"),
            "{summary}"
        );
        let rows = read_metrics(&out);
        let scored: Vec<f64> = rows.iter().filter_map(|r| r.ssim).collect();
        assert_eq!(scored.len(), 29, "{method:?}: every frame scored");
        let mean = scored.iter().sum::<f64>() / scored.len() as f64;
        assert!(mean > 0.3, "{method:?}: mean SSIM {mean}");
        let frame = std::fs::read_dir(out.join(&name))
            .expect("frames folder")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .find(|p| p.extension().is_some_and(|x| x == "png"))
            .expect("a frame");
        let img = image::open(&frame).expect("png").to_luma8();
        let (lo, hi) = img
            .pixels()
            .fold((255u8, 0u8), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
        assert!(
            hi - lo > 20,
            "{method:?}: {} is flat ({lo}..{hi})",
            frame.display()
        );
    }
}

/// `neuspike reconstruct --method auto` on a recording of the dark scene (600 planes, windows of
/// the policy's longest method, 256 planes, every 20; the calibration from its `recording.yml`):
/// with the event file the policy may choose any method; with the spike file alone, only those
/// that read spikes. Every window becomes a frame either way, none lost while a network
/// computes, and both beat what TFP over 33 planes gives there (about 12.7 dB).
#[test]
fn reconstruct_auto_chooses_per_window_with_or_without_events() {
    use neuspike::reconstruct::{Method, ReconstructOptions, reconstruct};
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = paired_recording(dir.path(), "dark-slow", 0.35);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for events in [Some(rec.join("events.raw")), None] {
        let out = dir
            .path()
            .join(if events.is_some() { "both" } else { "spikes" });
        let opts = ReconstructOptions {
            spikes: rec.join("spikes.dat"),
            events: events.clone(),
            truth: None,
            method: Method::Auto,
            model: None,
            policy: root.join("models/policy.yml"),
            out: out.clone(),
            source_args: String::new(),
            event_source_args: String::new(),
            infer_args: String::new(),
            window_planes: None,
            stride_planes: 20,
            bit_depth: 8,
            build: true,
        };
        let report = reconstruct(&opts).expect("reconstruct ran");
        assert!(report.failures.is_empty(), "{:?}", report.failures);
        let md = std::fs::read_to_string(out.join("summary.md")).expect("summary");
        // References at planes 128, 148, .., 448: 17 windows, each a frame.
        assert!(md.contains("| auto | 17 | 17 | 17 | 0 | yes |"), "{md}");
        assert!(md.contains("`auto`: the methods chosen"), "{md}");
        if events.is_none() {
            assert!(
                !md.contains("| neuspike-fused") && !md.contains("| neuspike-event"),
                "a method that reads events, without events: {md}"
            );
        }
        let rows = read_metrics(&out);
        let (_, psnr, _) = per_method_means(&rows);
        eprintln!("auto, events {}: {psnr:?}", events.is_some());
        assert!(psnr["auto"] > 18.0, "{psnr:?}");
    }
}

/// The learned graph on a dark scene (light x0.05, where TFP over 33 planes sees a spike or two a
/// pixel): every window becomes a frame from the network and from TFP, nothing is lost, every
/// frame is scored, and the network beats TFP on the same windows, as it does on the held-out set.
#[test]
fn learned_graph_runs_the_network_and_beats_tfp_in_the_dark() {
    let out = tempfile::tempdir().expect("tempdir");
    run("learned.yml", out.path(), &[]);
    let rows = read_metrics(out.path());
    let (n, psnr, _) = per_method_means(&rows);
    assert_eq!(
        psnr.keys().copied().collect::<Vec<_>>(),
        vec!["learned", "tfp"]
    );
    assert!(n >= 40, "only {n} frames");
    assert!(psnr["learned"] > psnr["tfp"] + 1.0, "{psnr:?}");
}

/// The example user node (`examples/rust-node`) in infer's place: every window becomes a scored
/// frame of its own method, nothing lost.
#[test]
fn a_users_rust_node_takes_infers_place() {
    let out = tempfile::tempdir().expect("tempdir");
    let graph = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/rust-node/graph.yml");
    let _one = one_graph();
    let report = neuspike::graph::run(
        &graph,
        &[(
            "sink".to_string(),
            format!("--out {}", out.path().display()),
        )],
        true,
        Some(Duration::from_secs(300)),
        None,
    )
    .expect("graph ran");
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let summary = std::fs::read_to_string(out.path().join("summary.md")).expect("summary");
    assert!(
        summary.contains("| gamma | 49 | 49 | 49 | 0 | yes |"),
        "{summary}"
    );
    let csv = std::fs::read_to_string(out.path().join("metrics.csv")).expect("metrics");
    let rows = csv
        .lines()
        .filter(|l| l.split(',').nth(2) == Some("gamma"))
        .count();
    assert_eq!(rows, 49, "{csv}");
}

/// `graphs/auto.yml`: the infer node chooses each window's method from the shipped policy. On the
/// dark scene it takes a network and beats what TFP gives there; under a 5 ms budget no network
/// fits, it falls back to spike methods, and the sink's summary reports the mix, the compute saved
/// and the frames late. Nothing is lost either way.
#[test]
fn the_auto_graph_chooses_per_window_and_keeps_a_budget() {
    let scene = [
        ("spike-source", "--scene dark-slow"),
        (
            "event-source",
            "--scene dark-slow --theta-on 0.35 --theta-off 0.35",
        ),
    ];
    let out = tempfile::tempdir().expect("tempdir");
    run("auto.yml", out.path(), &scene);
    let rows = read_metrics(out.path());
    let (n, psnr, _) = per_method_means(&rows);
    // dark-slow: 50 ms = 1,000 planes; 256-plane windows every 20 planes from plane 140 to 860.
    assert_eq!(n, 37, "{rows:?}");
    let md = std::fs::read_to_string(out.path().join("summary.md")).expect("summary");
    assert!(md.contains("| auto | 37 | 37 | 37 | 0 | yes |"), "{md}");
    // dark-slow moves at 100 px/s, below the grid's slowest motion: the policy's dark classes
    // up to 300 px/s take TFSTP (or, where its rows say faster, a network).
    assert!(
        md.contains("`auto`: the methods chosen")
            && (md.contains("| tfstp |") || md.contains("| neuspike-")),
        "{md}"
    );
    assert!(md.contains("saved"), "{md}");
    // TFP over 33 planes scores about 12.7 dB on this scene (README); TFSTP and the networks
    // far more.
    assert!(psnr["auto"] > 22.0, "{psnr:?}");

    let budget = tempfile::tempdir().expect("tempdir");
    let mut extra = scene.to_vec();
    extra.push(("infer-auto", "--budget-ms 5"));
    run("auto.yml", budget.path(), &extra);
    let md = std::fs::read_to_string(budget.path().join("summary.md")).expect("summary");
    assert!(md.contains("| auto | 37 | 37 | 37 | 0 | yes |"), "{md}");
    assert!(!md.contains("| neuspike-"), "a network in 5 ms? {md}");
    assert!(md.contains("Budget 5.000 ms a frame:"), "{md}");

    // Per region: every frame still comes, each tile's method in the `chosen` key.
    let regions = tempfile::tempdir().expect("tempdir");
    let mut extra = scene.to_vec();
    extra.push(("infer-auto", "--regions 80x50"));
    run("auto.yml", regions.path(), &extra);
    let rows = read_metrics(regions.path());
    let (n, psnr, _) = per_method_means(&rows);
    assert_eq!(n, 37, "{rows:?}");
    assert!(psnr["auto"] > 22.0, "{psnr:?}");
    let md = std::fs::read_to_string(regions.path().join("summary.md")).expect("summary");
    assert!(md.contains("`auto`: the methods chosen"), "{md}");
}

/// `neuspike` alone, as `cargo install` leaves it (no node binary beside it, no source checkout,
/// run from another folder), runs the demo serving as each of its nodes (`neuspike node KIND`):
/// the frames are those of the in-process chain, byte for byte, and nothing is lost; and it
/// reconstructs a recording with `--method auto` and with a learned model, found by their
/// default paths in its built-in copies.
#[test]
fn the_program_alone_runs_the_demo_serving_as_every_node() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bin = dir.path().join("bin");
    std::fs::create_dir_all(&bin).expect("mkdir");
    let program = bin.join("neuspike");
    std::fs::copy(env!("CARGO_BIN_EXE_neuspike"), &program).expect("copy the program");
    let work = dir.path().join("work");
    std::fs::create_dir_all(&work).expect("mkdir");
    let reference = tempfile::tempdir().expect("tempdir");
    let run = {
        let _one = one_graph();
        let sink = format!("--out {}", reference.path().display());
        neuspike::in_process::run(&graph("demo.yml"), &[("sink".to_string(), sink)])
            .expect("in process");
        std::process::Command::new(&program)
            .arg("demo")
            .current_dir(&work)
            .env_remove("CARGO_MANIFEST_DIR")
            .env_remove("CARGO_TARGET_DIR")
            .output()
            .expect("neuspike demo")
    };
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let out = work.join("out/demo");
    let written = std::fs::read_to_string(out.join("graph.yml")).expect("graph.yml");
    assert!(
        written.contains(&format!("path: {}", program.display()))
            && written.contains("args: node fused")
            && written.contains("args: node sink"),
        "{written}"
    );
    let (want, got) = (pngs(reference.path()), pngs(&out));
    assert!(want.len() >= 80, "{} frames", want.len());
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &want {
        assert!(got[name] == *bytes, "{name} differs");
    }
    // `--method auto` and a learned model by their default paths, which are not in this folder:
    // the built-in copies, written into the cache folder.
    let cache = dir.path().join("cache");
    let neuspike = |args: &[&str]| {
        let _one = one_graph();
        let run = std::process::Command::new(&program)
            .args(args)
            .current_dir(&work)
            .env_remove("CARGO_MANIFEST_DIR")
            .env_remove("CARGO_TARGET_DIR")
            .env("XDG_CACHE_HOME", &cache)
            .output()
            .expect("neuspike");
        assert!(
            run.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
    };
    neuspike(&["simulate", "bright-slow", "--out", "rec", "--planes", "600"]);
    for (method, model) in [
        ("auto", None),
        ("learned", Some("models/neuspike-spike-8.onnx")),
    ] {
        let out = format!("out/{method}");
        let mut args = vec![
            "reconstruct",
            "--spikes",
            "rec/spikes.dat",
            "--method",
            method,
        ];
        args.extend(model.iter().flat_map(|m| ["--model", *m]));
        args.extend(["--out", &out]);
        neuspike(&args);
        let summary: neuspike_sink::report::SummaryFile = serde_yaml::from_str(
            &std::fs::read_to_string(work.join(&out).join("summary.yml")).expect("summary.yml"),
        )
        .expect("summary");
        let (input, c) = summary.inputs.iter().next().expect("an input");
        let c = &c.counts;
        assert!(
            c.received >= 20 && c.missing == 0 && c.ended,
            "{method}: {input}: {c:?}"
        );
    }
    assert!(std::fs::read_dir(cache.join("neuspike")).is_ok_and(|mut d| d.next().is_some()));
}
