//! The node driven through its `run` loop with canned inputs.

use super::*;
use ndarray::{Array3, Axis};
use neuspike_reconstruction::Method;
use neuspike_reconstruction::learned::{LearnedInput, LearnedModel, LearnedOutput};
use neuspike_runtime::testing::{CannedInputs, output_ids};
#[allow(unused_imports)]
use neuspike_schemas::{AlignedWindow, EventBatch, Frame, Message, Representation};
use std::path::PathBuf;

fn rep(kind: &str, value: f32, seq: u64) -> Representation {
    let mut data = Array3::from_elem((if kind == "isi" { 2 } else { 1 }, 3, 4), value);
    if kind == "isi" {
        data.index_axis_mut(Axis(0), 1).fill(1.0); // every ISI measured
    }
    Representation {
        kind: kind.parse().unwrap(),
        t_ref_ns: 1_000_000 * (seq as i64 + 1),
        seq,
        params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
        data,
    }
}

/// The event stream's batch of window `seq`: `[seq ms, seq + 1 ms)`, with `n` ON events at
/// pixel (1, 2).
fn batch(seq: u64, n: usize, (h, w): (usize, usize)) -> EventBatch {
    let t0 = 1_000_000 * seq as i64;
    let mut b = EventBatch::empty(w, h, t0, t0 + 1_000_000, seq);
    for k in 0..n {
        b.push(neuspike_schemas::Event {
            t_ns: t0 + 1_000 * k as i64,
            x: 1,
            y: 2,
            polarity: 1,
        });
    }
    b
}

fn args(method: Method) -> InferConfig {
    InferConfig {
        method,
        ..InferConfig::default()
    }
}

/// The stage of a classical method, with both inputs in the graph.
fn stage(method: Method) -> Reconstructor {
    args(method)
        .reconstructor(&["representation".to_string(), "events".to_string()])
        .unwrap()
}

fn values(frame: &neuspike_runtime::testing::OutputJson) -> Vec<f64> {
    frame["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn tfp_frames_use_the_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
    c.message("representation", &rep("tfp", 0.25, 1)).unwrap();
    c.end::<Representation>("representation", 2).unwrap();
    let out = c
        .run(|node, events| run(node, events, stage(Method::Tfp)))
        .unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 3]);
    let v = values(&out[0]);
    assert_eq!(v.len(), 12);
    assert!(v.iter().all(|v| (v - 0.5).abs() < 1e-6), "{v:?}");
}

#[test]
fn wrong_representation_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
    let err = c
        .run(|node, events| run(node, events, stage(Method::Tfi)))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("`tfi` needs the `isi`") && err.contains("got `tfp`"),
        "{err}"
    );
}

#[test]
fn hf_reconstructs_from_the_event_stream_alone() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("events", &batch(0, 0, (3, 4))).unwrap();
    c.message("events", &batch(1, 3, (3, 4))).unwrap();
    c.end::<EventBatch>("events", 2).unwrap();
    let out = c
        .run(|node, events| run(node, events, stage(Method::Hf)))
        .unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 3]);
    let (first, second) = (values(&out[0]), values(&out[1]));
    // No events: every pixel at rest. Three ON events at (x 1, y 2): brighter there only.
    assert!(first.iter().all(|&v| v == first[0]), "{first:?}");
    let hit = 2 * 4 + 1;
    assert!(second[hit] > first[hit] * 1.5, "{second:?}");
    assert!(
        second
            .iter()
            .enumerate()
            .all(|(i, &v)| i == hit || v == first[0])
    );
}

#[test]
fn fusion_pairs_windows_by_sequence_whatever_the_arrival_order() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("events", &batch(0, 0, (3, 4))).unwrap();
    c.message("events", &batch(1, 2, (3, 4))).unwrap();
    c.message("representation", &rep("isi", 8.0, 0)).unwrap();
    c.end::<EventBatch>("events", 2).unwrap();
    // Window 1's ISI says invalid nowhere but is a bound-free measurement of the same light:
    // the anchor is re-measured; the two events in between count into theta's estimate.
    c.message("representation", &rep("isi", 8.0, 1)).unwrap();
    c.end::<Representation>("representation", 2).unwrap();
    let out = c
        .run(|node, events| run(node, events, stage(Method::Fusion)))
        .unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 3]);
    for f in &out[..2] {
        let v = values(f);
        // TFI of an 8-tick ISI at lum_per_rate 2: 0.25.
        assert!(v.iter().all(|v| (v - 0.25).abs() < 1e-6), "{v:?}");
    }
}

#[test]
fn event_sensor_of_another_size_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("events", &batch(0, 0, (260, 346))).unwrap();
    c.message("representation", &rep("isi", 8.0, 0)).unwrap();
    let err = c
        .run(|node, events| run(node, events, stage(Method::Fusion)))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("event sensor") && err.contains("[260, 346]"),
        "{err}"
    );
}

#[test]
fn a_graph_without_the_inputs_a_method_reads_is_refused_at_start_up() {
    let only_rep = ["representation".to_string()];
    let err = args(Method::Fusion)
        .reconstructor(&only_rep)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`fusion` needs an input `events`"), "{err}");
    let only_events = ["events".to_string()];
    let err = args(Method::Cf)
        .reconstructor(&only_events)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("`representation`") && err.contains("tfp or isi"),
        "{err}"
    );
    assert!(args(Method::Hf).reconstructor(&only_events).is_ok());
    let mut bad = args(Method::Hf);
    bad.contrast = -1.0;
    let err = bad.reconstructor(&only_events).unwrap_err().to_string();
    assert!(err.contains("contrast") && err.contains("-1"), "{err}");
}

fn models_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models")
}

/// The smallest shipped model whose inputs are `inputs`.
fn shipped_model(inputs: &[LearnedInput]) -> PathBuf {
    let mut models: Vec<PathBuf> = std::fs::read_dir(models_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "onnx"))
        .collect();
    models.sort_by_key(|p| (std::fs::metadata(p).unwrap().len(), p.clone()));
    models
        .into_iter()
        .find(|p| LearnedModel::load(p).unwrap().inputs() == inputs)
        .unwrap_or_else(|| panic!("a model reading {inputs:?} in models/"))
}

fn fused_model() -> PathBuf {
    shipped_model(&[LearnedInput::Spike, LearnedInput::Events])
}

fn learned_args(model: PathBuf) -> InferConfig {
    InferConfig {
        method: Method::Learned,
        model: Some(model),
        ..InferConfig::default()
    }
}

/// A representation of `kind` whose values are a fixed pattern (16 x 24, 32 channels).
fn pattern(kind: &str, seq: u64) -> Representation {
    let data = Array3::from_shape_fn((32, 16, 24), |(c, y, x)| {
        ((c * 5 + y * 3 + x) % 7) as f32 / 6.0
    });
    Representation {
        kind: kind.parse().unwrap(),
        t_ref_ns: 1_000_000 * (seq as i64 + 1),
        seq,
        params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
        data,
    }
}

#[test]
fn learned_frames_are_the_network_rate_calibrated() {
    let path = fused_model();
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    // Window 0's two representations arrive in either order; window 1 is spike first.
    c.message("event_integration", &pattern("event_integration", 0))
        .unwrap();
    c.message("spike_repr", &pattern("spike_repr", 0)).unwrap();
    c.message("spike_repr", &pattern("spike_repr", 1)).unwrap();
    c.message("event_integration", &pattern("event_integration", 1))
        .unwrap();
    c.end::<Representation>("spike_repr", 2).unwrap();
    c.end::<Representation>("event_integration", 2).unwrap();
    let inputs = ["spike_repr".to_string(), "event_integration".to_string()];
    let a = learned_args(path.clone());
    let stage = a.reconstructor(&inputs).unwrap();
    let out = c.run(|node, events| run(node, events, stage)).unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 3]);
    let mut direct = LearnedModel::load(&path).unwrap();
    let (s, e) = (pattern("spike_repr", 0), pattern("event_integration", 0));
    let rate = direct.run(&[s.data.view(), e.data.view()]).unwrap();
    for f in &out[..2] {
        let v = values(f);
        assert_eq!(v.len(), 16 * 24);
        for (got, r) in v.iter().zip(rate.iter()) {
            let want = (f64::from(*r) * 2.0).clamp(0.0, 1.0);
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        }
    }
}

#[test]
fn the_event_only_network_gives_luminance_without_the_spike_calibration() {
    let path = shipped_model(&[LearnedInput::Events]);
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("event_integration", &pattern("event_integration", 0))
        .unwrap();
    c.end::<Representation>("event_integration", 1).unwrap();
    let inputs = ["event_integration".to_string()];
    let a = learned_args(path.clone());
    let stage = a.reconstructor(&inputs).unwrap();
    assert_eq!(stage.model().unwrap().output(), LearnedOutput::Luminance);
    let out = c.run(|node, events| run(node, events, stage)).unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 2]);
    let e = pattern("event_integration", 0);
    let lum = LearnedModel::load(&path)
        .unwrap()
        .run(&[e.data.view()])
        .unwrap();
    let v = values(&out[0]);
    assert_eq!(v.len(), lum.len());
    // The pattern says lum_per_rate 2; a luminance output must not be doubled.
    for (got, l) in v.iter().zip(lum.iter()) {
        assert!((got - f64::from(*l)).abs() < 1e-6, "{got} vs {l}");
    }
}

#[test]
fn learned_refuses_a_representation_on_the_wrong_input() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("spike_repr", &pattern("event_integration", 0))
        .unwrap();
    c.message("event_integration", &pattern("event_integration", 0))
        .unwrap();
    let inputs = ["spike_repr".to_string(), "event_integration".to_string()];
    let a = learned_args(fused_model());
    let stage = a.reconstructor(&inputs).unwrap();
    let err = c
        .run(|node, events| run(node, events, stage))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("`spike_repr`")
            && err.contains("`event_integration`")
            && err.contains("reads `spike_repr`"),
        "{err}"
    );
}

#[test]
fn learned_is_checked_at_start_up() {
    let both = ["spike_repr".to_string(), "event_integration".to_string()];
    // No model.
    let mut a = learned_args(fused_model());
    a.model = None;
    let err = a.reconstructor(&both).unwrap_err().to_string();
    assert!(err.contains("--model"), "{err}");
    // A missing file, named.
    let err = learned_args(PathBuf::from("/nonexistent/net.onnx"))
        .reconstructor(&both)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("/nonexistent/net.onnx") && err.contains("cannot read"),
        "{err}"
    );
    // A graph that does not feed an input the model reads.
    let err = learned_args(fused_model())
        .reconstructor(&["spike_repr".to_string()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("connect an input `event_integration`"),
        "{err}"
    );
    // --model with a classical method.
    let mut a = args(Method::Tfp);
    a.model = Some(fused_model());
    let err = a
        .reconstructor(&["representation".to_string()])
        .unwrap_err()
        .to_string();
    assert!(err.contains("`--model` is for `--method learned`"), "{err}");
    // And the method names: learned is accepted, the list of names says so.
    assert_eq!("learned".parse::<Method>().unwrap(), Method::Learned);
    let e = "nope".parse::<Method>().unwrap_err().to_string();
    assert!(e.contains("learned"), "{e}");
}

/// Window `seq` of `n` planes of 40 x 48 with a fixed pattern of spikes, no events.
fn spike_window(seq: u64, n: usize) -> AlignedWindow {
    let (h, w): (usize, usize) = (40, 48);
    let per = (h * w).div_ceil(8);
    let bits = (0..n * per)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 7) as u8 & (0x55 << (i % 2)))
        .collect();
    let spikes = neuspike_schemas::SpikeChunk {
        width: w,
        height: h,
        first_plane: seq * n as u64,
        n_planes: n,
        t_first_ns: 1_000_000 * seq as i64,
        plane_period_ns: 50_000,
        seq,
        bits,
        lum_per_rate: Some(2.0),
    };
    AlignedWindow {
        t_ref_ns: spikes.plane_time_ns(n / 2),
        ref_plane: seq * n as u64 + (n / 2) as u64,
        spikes,
        events: EventBatch::empty(0, 0, 0, 1, seq),
    }
}

/// A spike network fed align's windows makes, in 8 bits, the frames it makes of the represent
/// stage's spike representation of the same windows: its raw planes read packed.
#[test]
fn a_spike_network_reads_the_windows_themselves() {
    use neuspike_reconstruction::learned::Precision;
    use neuspike_representations::{RepresentConfig, Representer};
    let path = shipped_model(&[LearnedInput::Spike]);
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    let windows: Vec<AlignedWindow> = (0..2).map(|seq| spike_window(seq, 33)).collect();
    for w in &windows {
        c.message("windows", w).unwrap();
    }
    c.end::<AlignedWindow>("windows", 2).unwrap();
    let mut a = learned_args(path.clone());
    a.precision = Precision::int8();
    let stage = a.reconstructor(&["windows".to_string()]).unwrap();
    assert_eq!(stage.input_ids(), vec!["windows"]);
    let out = c.run(|node, events| run(node, events, stage)).unwrap();
    assert_eq!(output_ids(&out), vec!["frames"; 3]);
    let mut direct = LearnedModel::load(&path).unwrap();
    direct.set_precision(Precision::int8());
    let mut represent = Representer::new(RepresentConfig {
        repr_channels: direct.channels()[0] as u32,
        ..RepresentConfig::default()
    })
    .unwrap();
    for (w, frame) in windows.iter().zip(&out) {
        let rep = represent
            .represent(neuspike_schemas::RepresentationKind::SpikeRepr, w)
            .unwrap();
        let rate = direct.run(&[rep.data.view()]).unwrap();
        // The stage's frame is the network's own from the window; the representation made in
        // `f32` first gives nearly the same (on AVX-512 the planes' convolution runs in `f32`
        // by tables, not in 8 bits).
        let from_window = direct.run_window(w, &mut represent).unwrap();
        let v = values(frame);
        assert_eq!(v.len(), 40 * 48);
        for ((got, r), rw) in v.iter().zip(rate.iter()).zip(from_window.iter()) {
            let want = (f64::from(*rw) * 2.0).clamp(0.0, 1.0);
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
            let represented = (f64::from(*r) * 2.0).clamp(0.0, 1.0);
            assert!((got - represented).abs() < 0.05, "{got} vs {represented}");
        }
    }
    // Windows and the representation both connected: refused, by name.
    let err = learned_args(path)
        .reconstructor(&["windows".to_string(), "spike_repr".to_string()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("either `windows`") && err.contains("spike_repr"),
        "{err}"
    );
}
