//! The node driven through its `run` loop with canned inputs.

use super::*;
use ndarray::{Array3, Axis};
use neuspike_runtime::testing::{CannedInputs, output_ids};
#[allow(unused_imports)]
use neuspike_schemas::{AlignedWindow, Message, Representation};
use neuspike_schemas::{EventBatch, SpikeChunk, pack_planes};

fn window(seq: u64) -> AlignedWindow {
    // 4x2 pixels, 5 planes; pixel 0 fires every plane, the others never.
    let mut p = Array3::<u8>::zeros((5, 2, 4));
    p.index_axis_mut(Axis(2), 0)
        .index_axis_mut(Axis(1), 0)
        .fill(1);
    let spikes = SpikeChunk {
        width: 4,
        height: 2,
        first_plane: 10,
        n_planes: 5,
        t_first_ns: 0,
        plane_period_ns: 10,
        seq,
        bits: pack_planes(p.view()),
        lum_per_rate: Some(1.0),
    };
    AlignedWindow {
        t_ref_ns: 20,
        ref_plane: 12,
        spikes,
        events: EventBatch::empty(4, 2, -10, 40, seq),
    }
}

/// Small settings for the tests; TFSTP's are the defaults.
fn representer() -> Representer {
    Representer::new(RepresentConfig {
        repr_channels: 4,
        ei_channels: 2,
        tau_ns: 5.0,
        ..RepresentConfig::default()
    })
    .unwrap()
}

#[test]
fn computes_only_declared_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("windows", &window(0)).unwrap();
    c.end::<AlignedWindow>("windows", 1).unwrap();
    let kinds = [
        RepresentationKind::Tfp,
        RepresentationKind::EventIntegration,
    ];
    let out = c
        .run(|node, events| run(node, events, representer(), &kinds))
        .unwrap();
    assert_eq!(
        output_ids(&out),
        vec!["tfp", "event_integration", "tfp", "event_integration"]
    );
    let tfp: Vec<f64> = out[0]["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(tfp, vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
}

#[test]
fn every_kind_goes_out_on_the_output_of_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    c.message("windows", &window(0)).unwrap();
    c.end::<AlignedWindow>("windows", 1).unwrap();
    let out = c
        .run(|node, events| run(node, events, representer(), &RepresentationKind::ALL))
        .unwrap();
    let names: Vec<&str> = RepresentationKind::ALL.iter().map(|k| k.name()).collect();
    // One message per kind, then one end-of-stream marker per kind.
    assert_eq!(output_ids(&out), [names.clone(), names].concat());
}

/// `stp` keeps its synapses from window to window: windows of 5 planes every 3, each fed up
/// to its reference plane (its third), see the planes of one stream once each.
#[test]
fn stp_carries_its_synapses_across_windows() {
    // Pixel 0 fires every plane, pixel 1 every third plane (0 mod 3), the others never.
    let stream = |first: u64, seq: u64| {
        let p = Array3::<u8>::from_shape_fn((5, 2, 4), |(k, y, x)| {
            let plane = first + k as u64;
            u8::from((y, x) == (0, 0) || ((y, x) == (0, 1) && plane.is_multiple_of(3)))
        });
        let mut w = window(seq);
        w.spikes.bits = pack_planes(p.view());
        w.spikes.first_plane = first;
        w.spikes.t_first_ns = first as i64 * 10;
        w.ref_plane = first + 2;
        w.t_ref_ns = w.ref_plane as i64 * 10;
        w
    };
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    for (seq, first) in [10u64, 13, 16].into_iter().enumerate() {
        c.message("windows", &stream(first, seq as u64)).unwrap();
    }
    c.end::<AlignedWindow>("windows", 3).unwrap();
    let out = c
        .run(|node, events| run(node, events, representer(), &[RepresentationKind::Stp]))
        .unwrap();
    // Three windows and the end-of-stream marker.
    assert_eq!(output_ids(&out), vec!["stp"; 4]);
    let pixel =
        |m: &neuspike_runtime::testing::OutputJson, i: usize| m["data"][i].as_f64().unwrap();
    // Window 1 (planes 10..12): pixel 1's first spike (12) has no interval yet. Window 2 feeds
    // 13..15 and finds the interval 12 -> 15, which a window alone (13..15) could not.
    let third = f64::from(1.0f32 / 3.0);
    let got: Vec<[f64; 3]> = out[..3]
        .iter()
        .map(|m| [pixel(m, 0), pixel(m, 1), pixel(m, 2)])
        .collect();
    assert_eq!(got, [[1.0, 0.0, 0.0], [1.0, third, 0.0], [1.0, third, 0.0]]);
}
