//! dora node: representations of aligned windows. Input `windows` (AlignedWindow); one output per
//! representation kind, computed only when the graph declares it: `tfp`, `isi`, `spike_repr`,
//! `event_integration`, `stp` (all Representation).
//!
//! `stp` (TFSTP's rate, `StpFilter`) is the one with state across windows: each pixel's synapse
//! is fed every plane once, up to each window's reference plane (the planes after it wait for
//! the next window), and read there. Windows that leave planes out are gaps: the synapses forget
//! their last spike there, and the count travels as the `gaps` parameter.

use std::collections::BTreeMap;

use dora_node_api::{DoraNode, Event, EventStream};
use ndarray::{Array2, Array3, Axis};
use neuspike_represent::{
    EventSlice, StpFilter, StpParams, event_integration_into, integration_instants,
    isi_packed_into, spike_representation_packed_into, tfp_packed_into,
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
    /// TFSTP (`stp`): the synapse's release probability at rest, U, in (0, 1).
    #[arg(long, default_value_t = StpParams::default().u0)]
    stp_u0: f64,
    /// TFSTP (`stp`): the facilitation increment per spike, f, in (0, 1].
    #[arg(long, default_value_t = StpParams::default().f)]
    stp_f: f64,
    /// TFSTP (`stp`): the resources' recovery time constant D, in planes (ticks).
    #[arg(long, default_value_t = StpParams::default().tau_d_ticks)]
    stp_tau_d_ticks: f64,
    /// TFSTP (`stp`): the facilitation's time constant F, in planes (ticks).
    #[arg(long, default_value_t = StpParams::default().tau_f_ticks)]
    stp_tau_f_ticks: f64,
}

impl Args {
    fn stp_params(&self) -> StpParams {
        StpParams {
            u0: self.stp_u0,
            f: self.stp_f,
            tau_d_ticks: self.stp_tau_d_ticks,
            tau_f_ticks: self.stp_tau_f_ticks,
        }
    }
}

/// The representation kinds, by output id.
const KINDS: [(&str, &str); 5] = [
    ("tfp", "tfp"),
    ("isi", "isi"),
    ("spike_repr", "spike-repr"),
    ("event_integration", "event-integration"),
    ("stp", "stp"),
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
    args.stp_params()
        .check()
        .map_err(|e| eyre::eyre!("represent: {e}"))?;
    let (node, events) = DoraNode::init_from_env()?;
    let outputs: Vec<String> = node
        .node_config()
        .outputs
        .iter()
        .map(|o| o.to_string())
        .collect();
    node::run_on_rayon("represent", || run(node, events, &args, &outputs))
}

/// Computes the representation of one kind for a window; `stp` carries TFSTP's synapses from
/// window to window (made at the first window, and again when the sensor size changes).
fn represent(
    kind: &str,
    w: &AlignedWindow,
    args: &Args,
    stp: &mut Option<StpFilter>,
) -> eyre::Result<Representation> {
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
        "stp" => {
            let f = match stp {
                Some(f) if f.dim() == (h, wd) => f,
                _ => stp.insert(StpFilter::new(h, wd, args.stp_params())?),
            };
            f.advance_packed(&w.spikes.bits, w.spikes.first_plane, n, w.ref_plane)?;
            params.insert("gaps".into(), f.gaps() as f64);
            let mut dst = Array2::<f32>::zeros((h, wd));
            f.rate_into(dst.view_mut())?;
            dst.insert_axis(Axis(0))
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
    let mut stp = None;
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
                    let r = represent(kind, &w, args, &mut stp)?;
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

    /// Small settings for the tests; TFSTP's are the defaults.
    fn test_args() -> Args {
        let stp = StpParams::default();
        Args {
            tfp_planes: None,
            repr_channels: 4,
            ei_channels: 2,
            tau_ns: 5.0,
            stp_u0: stp.u0,
            stp_f: stp.f,
            stp_tau_d_ticks: stp.tau_d_ticks,
            stp_tau_f_ticks: stp.tau_f_ticks,
        }
    }

    #[test]
    fn computes_only_declared_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("windows", &window(0)).unwrap();
        c.end::<AlignedWindow>("windows", 1).unwrap();
        let args = test_args();
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
        let args = test_args();
        let outputs = vec!["stp".to_string()];
        let out = c
            .run(|node, events| run(node, events, &args, &outputs))
            .unwrap();
        // Three windows and the end-of-stream marker.
        assert_eq!(output_ids(&out), vec!["stp"; 4]);
        let pixel =
            |m: &neuspike_schemas::testing::OutputJson, i: usize| m["data"][i].as_f64().unwrap();
        // Window 1 (planes 10..12): pixel 1's first spike (12) has no interval yet. Window 2 feeds
        // 13..15 and finds the interval 12 -> 15, which a window alone (13..15) could not.
        let third = f64::from(1.0f32 / 3.0);
        let got: Vec<[f64; 3]> = out[..3]
            .iter()
            .map(|m| [pixel(m, 0), pixel(m, 1), pixel(m, 2)])
            .collect();
        assert_eq!(got, [[1.0, 0.0, 0.0], [1.0, third, 0.0], [1.0, third, 0.0]]);
    }
}
