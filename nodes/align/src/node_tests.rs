//! The node driven through its `run` loop with canned inputs.

use super::*;
use neuspike_runtime::testing::{CannedInputs, output_ids, payload_len};
#[allow(unused_imports)]
use neuspike_schemas::{AlignedWindow, EventBatch, Message, SpikeChunk};

fn chunk(first: u64, n: usize, seq: u64) -> SpikeChunk {
    SpikeChunk {
        width: 8,
        height: 2,
        first_plane: first,
        n_planes: n,
        t_first_ns: first as i64 * 50_000,
        plane_period_ns: 50_000,
        seq,
        bits: vec![0b1010_0101; 2 * n],
        lum_per_rate: Some(1.0),
    }
}

#[test]
fn windows_then_end_of_stream() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    for i in 0..5 {
        c.message("spikes", &chunk(i * 20, 20, i)).unwrap();
    }
    c.end::<SpikeChunk>("spikes", 5).unwrap();
    c.end::<EventBatch>("events", 0).unwrap();
    let cfg = AlignConfig {
        window_planes: 33,
        stride_planes: 20,
        fps: None,
        event_offset_ns: 0,
        homography: None,
        ..Default::default()
    };
    let out = c
        .run(|node, events| run(node, events, AlignStage::new(cfg, true, false)))
        .unwrap();
    // 100 planes: references 20, 40, 60, 80 (80 + 16 = 96 <= 99; 100 would need plane 116).
    assert_eq!(output_ids(&out), vec!["windows"; 5]);
    assert_eq!(payload_len(&out[0]), 1, "one row per window");
    assert_eq!(payload_len(&out[4]), 0, "end-of-stream marker");
}

#[test]
fn event_stream_follows_each_window_and_ends() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    for i in 0..5 {
        c.message("spikes", &chunk(i * 20, 20, i)).unwrap();
    }
    c.end::<SpikeChunk>("spikes", 5).unwrap();
    let mut batch = EventBatch::empty(8, 2, 0, 5_000_000, 0);
    for k in 0..50 {
        batch.push(neuspike_schemas::Event {
            t_ns: k * 100_000,
            x: 1,
            y: 1,
            polarity: 1,
        });
    }
    c.message("events", &batch).unwrap();
    c.end::<EventBatch>("events", 1).unwrap();
    let cfg = AlignConfig {
        window_planes: 33,
        stride_planes: 20,
        fps: None,
        event_offset_ns: 0,
        homography: None,
        ..Default::default()
    };
    let out = c
        .run(|node, events| run(node, events, AlignStage::new(cfg, true, true)))
        .unwrap();
    let ids = output_ids(&out);
    assert_eq!(
        ids,
        [["windows", "events"]; 4]
            .concat()
            .into_iter()
            .chain(["windows", "events"])
            .collect::<Vec<_>>()
    );
    // References at planes 20, 40, 60, 80 (t = 1, 2, 3, 4 ms): the batches hold the events
    // before 1 ms, then 10 each.
    let lens: Vec<usize> = out.iter().skip(1).step_by(2).map(payload_len).collect();
    assert_eq!(lens, vec![10, 10, 10, 10, 0]);
}

#[test]
fn bad_chunk_stops_with_a_named_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = CannedInputs::new(dir.path());
    let mut bad = chunk(0, 4, 0);
    bad.bits.pop();
    let (meta, _) = bad.to_arrow();
    let data: neuspike_schemas::arrow::array::ArrayRef = std::sync::Arc::new(
        neuspike_schemas::arrow::array::UInt8Array::from(bad.bits.clone()),
    );
    c.raw("spikes", meta, data).unwrap();
    let err = c
        .run(|node, events| {
            run(
                node,
                events,
                AlignStage::new(AlignConfig::default(), false, false),
            )
        })
        .unwrap_err();
    assert!(format!("{err:#}").contains("7 bytes"), "{err:#}");
}
