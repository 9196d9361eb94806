//! dora node: representations of aligned windows. Input `windows` (AlignedWindow); one output per
//! representation kind, computed only when the graph declares it: `tfp`, `isi`, `spike_repr`,
//! `event_integration` (all Representation).

use std::collections::BTreeMap;

use dora_node_api::{DoraNode, Event, EventStream};
use ndarray::{Array2, Array3, Axis};
use neuspike_represent::{
    EventSlice, event_integration_into, integration_instants, isi_packed_into,
    spike_representation_packed_into, tfp_packed_into,
};
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{
    AlignedWindow, Message, Representation, SeqStatus, SeqTracker, is_end_of_stream,
};

/// Node arguments (the graph's `args:`).
#[derive(Clone, Debug, clap::Parser)]
#[command(
    name = "neuspike-represent",
    about = "Spike and event representations",
    args_override_self = true
)]
struct Args {
    /// TFP window in planes, centred on the reference plane (default: the whole aligned window).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    tfp_planes: Option<u32>,
    /// Channels of the NeuSpike-Net spike representation (1 ISI + N-1 planes).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(2..))]
    repr_channels: u32,
    /// Channels of the event integration (instants evenly spaced over the window).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..))]
    ei_channels: u32,
    /// Decay constant tau of the event integration (paper Eq. 8), nanoseconds.
    #[arg(long, default_value_t = 500_000.0)]
    tau_ns: f64,
}

/// The representation kinds, by output id.
const KINDS: [(&str, &str); 4] = [
    ("tfp", "tfp"),
    ("isi", "isi"),
    ("spike_repr", "spike-repr"),
    ("event_integration", "event-integration"),
];

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("represent")?;
    if args.tau_ns.is_nan() || args.tau_ns < 0.0 {
        eyre::bail!(
            "represent: `tau-ns` = {} is invalid: must be >= 0 (inf allowed)",
            args.tau_ns
        );
    }
    let (node, events) = DoraNode::init_from_env()?;
    let outputs: Vec<String> = node
        .node_config()
        .outputs
        .iter()
        .map(|o| o.to_string())
        .collect();
    node::run_on_rayon("represent", || run(node, events, &args, &outputs))
}

/// Computes the representation of one kind for a window.
fn represent(kind: &str, w: &AlignedWindow, args: &Args) -> eyre::Result<Representation> {
    let (n, h, wd) = (w.spikes.n_planes, w.spikes.height, w.spikes.width);
    let c = w.ref_index();
    let mut params = BTreeMap::new();
    if let Some(g) = w.spikes.lum_per_rate {
        params.insert("lum_per_rate".to_string(), g);
    }
    let data = match kind {
        "tfp" => {
            let len = args.tfp_planes.map_or(n, |p| (p as usize).min(n));
            let start = c.saturating_sub(len / 2).min(n - len);
            params.insert("window".into(), len as f64);
            let mut dst = Array2::<f32>::zeros((h, wd));
            // Straight from the packed planes: no unpacking.
            tfp_packed_into(&w.spikes.bits, start..start + len, dst.view_mut())?;
            dst.insert_axis(Axis(0))
        }
        "isi" => {
            let mut isi = Array2::<f32>::zeros((h, wd));
            let mut valid = Array2::<bool>::from_elem((h, wd), false);
            // Straight from the packed planes: no unpacking.
            isi_packed_into(&w.spikes.bits, n, c, isi.view_mut(), valid.view_mut())?;
            let mut out = Array3::<f32>::zeros((2, h, wd));
            out.index_axis_mut(Axis(0), 0).assign(&isi);
            out.index_axis_mut(Axis(0), 1)
                .assign(&valid.mapv(|v| f32::from(u8::from(v))));
            out
        }
        "spike-repr" => {
            let ch = args.repr_channels as usize;
            params.insert("channels".into(), ch as f64);
            let mut out = Array3::<f32>::zeros((ch, h, wd));
            // Straight from the packed planes: no unpacking.
            spike_representation_packed_into(&w.spikes.bits, n, c, out.view_mut())?;
            out
        }
        "event-integration" => {
            let k = args.ei_channels as usize;
            let ev = &w.events;
            let (eh, ew) = (ev.height.max(1), ev.width.max(1));
            let ts = integration_instants(ev.t_start_ns, ev.t_end_ns, k);
            params.insert("tau_ns".into(), args.tau_ns);
            let slice = EventSlice {
                t_ns: &ev.t_ns,
                x: &ev.x,
                y: &ev.y,
                polarity: &ev.polarity,
            };
            let mut out = Array3::<f32>::zeros((k, eh, ew));
            event_integration_into(slice, ev.t_start_ns, &ts, args.tau_ns, out.view_mut())?;
            out
        }
        other => eyre::bail!("represent: unknown representation kind `{other}`"),
    };
    Ok(Representation {
        kind: kind.to_string(),
        t_ref_ns: w.t_ref_ns,
        seq: w.seq(),
        params,
        data,
    })
}

fn run(
    mut node: DoraNode,
    mut events: EventStream,
    args: &Args,
    outputs: &[String],
) -> eyre::Result<()> {
    let active: Vec<(&str, &str)> = KINDS
        .iter()
        .copied()
        .filter(|(id, _)| outputs.iter().any(|o| o == id))
        .collect();
    tracing::info!(outputs = ?active.iter().map(|a| a.0).collect::<Vec<_>>(), "represent started");
    let mut seq = SeqTracker::default();
    let mut sent = 0u64;
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data } if AsRef::<str>::as_ref(&id) == "windows" => {
                let meta = &metadata.parameters;
                if let Some(count) = is_end_of_stream(meta) {
                    let lost = seq.end(count);
                    if lost > 0 {
                        tracing::error!(lost, "windows lost at the end of the stream");
                    }
                    break;
                }
                let w = AlignedWindow::from_arrow(meta, data.as_array())?;
                if let SeqStatus::Gap { missing } = seq.observe(w.seq()) {
                    tracing::error!(seq = w.seq(), missing, "windows lost before this one");
                }
                for (id, kind) in &active {
                    let r = represent(kind, &w, args)?;
                    send(&mut node, &output(id), &r)?;
                }
                // Sequence numbers follow the windows', so a lost window shows downstream too.
                sent = w.seq() + 1;
            }
            Event::Input { id, .. } => tracing::warn!(input = %id, "unknown input ignored"),
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs: only the
            // end-of-stream marker, or the end of the event stream, ends the loop.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the input"),
            _ => {}
        }
    }
    for (id, _) in &active {
        send_end::<Representation>(&mut node, &output(id), sent)?;
    }
    tracing::info!(windows = sent, lost = seq.missing(), "represent finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::testing::{CannedInputs, output_ids};
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

    #[test]
    fn computes_only_declared_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("windows", &window(0)).unwrap();
        c.end::<AlignedWindow>("windows", 1).unwrap();
        let args = Args {
            tfp_planes: None,
            repr_channels: 4,
            ei_channels: 2,
            tau_ns: 5.0,
        };
        let outputs = vec!["tfp".to_string(), "event_integration".to_string()];
        let out = c
            .run(|node, events| run(node, events, &args, &outputs))
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
}
