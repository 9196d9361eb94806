//! dora node: aligns the spike and event streams. Inputs `spikes` (SpikeChunk) and, optionally,
//! `events` (EventBatch); output `windows` (AlignedWindow) and, when the graph declares it,
//! `events` (EventBatch): the event stream on the spike clock cut at every window's reference
//! instant, each event once (what the event filters of `infer` take).

use dora_node_api::{DoraNode, Event, EventStream};
use neuspike_align::{AlignConfig, Aligner};
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{
    AlignedWindow, EventBatch, Message, SeqStatus, SeqTracker, SpikeChunk, is_end_of_stream,
};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-align",
    about = "Aligns spikes and events into windows",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    align: AlignConfig,
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("align")?;
    let (node, events) = DoraNode::init_from_env()?;
    let with_events = node
        .node_config()
        .inputs
        .keys()
        .any(|k| AsRef::<str>::as_ref(k) == "events");
    let with_stream = node
        .node_config()
        .outputs
        .iter()
        .any(|o| AsRef::<str>::as_ref(o) == "events");
    let mut aligner = Aligner::new(args.align, with_events);
    if with_stream {
        aligner = aligner.with_event_stream();
    }
    run(node, events, aligner)
}

/// Sends every ready window, each followed by its batch of the event stream (if wanted).
fn send_ready(node: &mut DoraNode, aligner: &mut Aligner) -> eyre::Result<()> {
    while let Some(window) = aligner.pop_ready() {
        send::<AlignedWindow>(node, &output("windows"), &window)?;
        if let Some(batch) = aligner.pop_stream() {
            send::<EventBatch>(node, &output("events"), &batch)?;
        }
    }
    Ok(())
}

fn observe(tracker: &mut SeqTracker, input: &str, seq: u64) {
    match tracker.observe(seq) {
        SeqStatus::InOrder => {}
        SeqStatus::Gap { missing } => {
            tracing::error!(input, seq, missing, "messages lost before this one")
        }
        SeqStatus::Stale => tracing::warn!(input, seq, "stale message"),
    }
}

fn run(mut node: DoraNode, mut events: EventStream, mut aligner: Aligner) -> eyre::Result<()> {
    let (mut spike_seq, mut event_seq) = (SeqTracker::default(), SeqTracker::default());
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } => {
                let meta = &metadata.parameters;
                let data = data.as_array();
                match AsRef::<str>::as_ref(&id) {
                    "spikes" => {
                        if let Some(count) = is_end_of_stream(meta) {
                            let lost = spike_seq.end(count);
                            if lost > 0 {
                                tracing::error!(lost, "spike chunks lost at the end of the stream");
                            }
                            aligner.close_spikes();
                        } else {
                            let chunk = SpikeChunk::from_arrow(meta, data)?;
                            observe(&mut spike_seq, "spikes", chunk.seq);
                            aligner.push_spikes(chunk)?;
                        }
                    }
                    "events" => {
                        if let Some(count) = is_end_of_stream(meta) {
                            let lost = event_seq.end(count);
                            if lost > 0 {
                                tracing::error!(
                                    lost,
                                    "event batches lost at the end of the stream"
                                );
                            }
                            aligner.close_events();
                        } else {
                            let batch = EventBatch::from_arrow(meta, data)?;
                            observe(&mut event_seq, "events", batch.seq);
                            aligner.push_events(batch);
                        }
                    }
                    other => tracing::warn!(input = other, "unknown input ignored"),
                }
            }
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs of a
            // stream: the end-of-stream markers (or the end of the event stream) end a stream.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the inputs"),
            _ => {}
        }
        send_ready(&mut node, &mut aligner)?;
        if aligner.finished() {
            break;
        }
    }
    aligner.close_spikes();
    aligner.close_events();
    send_ready(&mut node, &mut aligner)?;
    send_end::<AlignedWindow>(&mut node, &output("windows"), aligner.emitted())?;
    if aligner.streams_events() {
        send_end::<EventBatch>(&mut node, &output("events"), aligner.emitted())?;
    }
    tracing::info!(
        windows = aligner.emitted(),
        skipped = aligner.skipped_windows(),
        spike_chunks_lost = spike_seq.missing(),
        event_batches_lost = event_seq.missing(),
        "align finished"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::testing::{CannedInputs, output_ids, payload_len};

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
        };
        let out = c
            .run(|node, events| run(node, events, Aligner::new(cfg, true)))
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
        };
        let out = c
            .run(|node, events| run(node, events, Aligner::new(cfg, true).with_event_stream()))
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
            .run(|node, events| run(node, events, Aligner::new(AlignConfig::default(), false)))
            .unwrap_err();
        assert!(format!("{err:#}").contains("7 bytes"), "{err:#}");
    }
}
