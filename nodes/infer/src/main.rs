//! dora node: reconstruction. Input `representation` (Representation of the kind the method
//! needs); output `frames` (Frame). Methods: `tfp` (needs `tfp`), `tfi` (needs `isi`).

use std::time::Instant;

use dora_node_api::{DoraNode, Event, EventStream};
use ndarray::{Array2, Axis};
use neuspike_infer::{Method, luminance_from_isi_into, luminance_from_rate_into};
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{
    Frame, FrameKind, Message, Representation, SeqStatus, SeqTracker, is_end_of_stream,
};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-infer",
    about = "Reconstructs frames from a representation",
    args_override_self = true
)]
struct Args {
    /// Reconstruction method: tfp or tfi.
    #[arg(long, default_value = "tfp")]
    method: Method,
    /// Luminance per unit firing rate (overrides the calibration the spike source sends).
    #[arg(long)]
    lum_per_rate: Option<f64>,
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("infer")?;
    if let Some(g) = args.lum_per_rate
        && !(g.is_finite() && g > 0.0)
    {
        eyre::bail!("infer: `lum-per-rate` = {g} is invalid: must be finite and > 0");
    }
    let (node, events) = DoraNode::init_from_env()?;
    run(node, events, &args)
}

/// Reconstructs one frame.
fn reconstruct(method: Method, r: &Representation, gain: f64) -> eyre::Result<Array2<f32>> {
    let expected = method.required_representation();
    if r.kind != expected {
        eyre::bail!(
            "infer: method `{method}` needs the `{expected}` representation, got `{}` (connect the represent node's `{expected}` output)",
            r.kind
        );
    }
    let (_, h, w) = r.data.dim();
    let mut dst = Array2::<f32>::zeros((h, w));
    // The luminance formulas take phi and the light scale; lum_per_rate = phi / light_scale.
    match method {
        Method::Tfp => {
            luminance_from_rate_into(r.data.index_axis(Axis(0), 0), gain, 1.0, dst.view_mut())?
        }
        Method::Tfi => {
            luminance_from_isi_into(r.data.index_axis(Axis(0), 0), gain, 1.0, dst.view_mut())?
        }
    }
    Ok(dst)
}

fn run(mut node: DoraNode, mut events: EventStream, args: &Args) -> eyre::Result<()> {
    let out = output("frames");
    let mut seq = SeqTracker::default();
    let mut count = 0u64;
    while let Some(event) = events.recv() {
        match event {
            Event::Input { id, metadata, data }
                if AsRef::<str>::as_ref(&id) == "representation" =>
            {
                let meta = &metadata.parameters;
                if let Some(n) = is_end_of_stream(meta) {
                    let lost = seq.end(n);
                    if lost > 0 {
                        tracing::error!(lost, "representations lost at the end of the stream");
                    }
                    count = count.max(n);
                    break;
                }
                let r = Representation::from_arrow(meta, data.as_array())?;
                if let SeqStatus::Gap { missing } = seq.observe(r.seq) {
                    tracing::error!(seq = r.seq, missing, "representations lost before this one");
                }
                let gain = match args
                    .lum_per_rate
                    .or_else(|| r.params.get("lum_per_rate").copied())
                {
                    Some(g) => g,
                    None => eyre::bail!(
                        "infer: no calibration: the representation carries no `lum_per_rate` and the graph sets no `--lum-per-rate`"
                    ),
                };
                let start = Instant::now();
                let data = reconstruct(args.method, &r, gain)?;
                let frame = Frame {
                    kind: FrameKind::Reconstruction,
                    method: args.method.to_string(),
                    t_ref_ns: r.t_ref_ns,
                    compute_ns: i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX),
                    seq: r.seq,
                    data,
                };
                send(&mut node, &out, &frame)?;
                count = r.seq + 1;
            }
            Event::Input { id, .. } => tracing::warn!(input = %id, "unknown input ignored"),
            // dora's scheduler may yield `InputClosed` and `Stop` before the last inputs: only the
            // end-of-stream marker, or the end of the event stream, ends the loop.
            Event::InputClosed { id } => tracing::debug!(input = %id, "input closed"),
            Event::Stop(cause) => tracing::debug!(?cause, "stop received; draining the input"),
            _ => {}
        }
    }
    send_end::<Frame>(&mut node, &out, count)?;
    tracing::info!(frames = count, lost = seq.missing(), method = %args.method, "infer finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use neuspike_schemas::testing::{CannedInputs, output_ids};

    fn rep(kind: &str, value: f32, seq: u64) -> Representation {
        Representation {
            kind: kind.into(),
            t_ref_ns: 1_000 * seq as i64,
            seq,
            params: [("lum_per_rate".to_string(), 2.0)].into_iter().collect(),
            data: Array3::from_elem((if kind == "isi" { 2 } else { 1 }, 3, 4), value),
        }
    }

    #[test]
    fn tfp_frames_use_the_calibration() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        c.message("representation", &rep("tfp", 0.25, 1)).unwrap();
        c.end::<Representation>("representation", 2).unwrap();
        let args = Args {
            method: Method::Tfp,
            lum_per_rate: None,
        };
        let out = c.run(|node, events| run(node, events, &args)).unwrap();
        assert_eq!(output_ids(&out), vec!["frames"; 3]);
        let values = out[0]["data"].as_array().unwrap();
        assert_eq!(values.len(), 12);
        assert!(
            values
                .iter()
                .all(|v| (v.as_f64().unwrap() - 0.5).abs() < 1e-6),
            "{values:?}"
        );
    }

    #[test]
    fn wrong_representation_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = CannedInputs::new(dir.path());
        c.message("representation", &rep("tfp", 0.25, 0)).unwrap();
        let args = Args {
            method: Method::Tfi,
            lum_per_rate: None,
        };
        let err = c
            .run(|node, events| run(node, events, &args))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`tfi` needs the `isi`") && err.contains("got `tfp`"),
            "{err}"
        );
    }
}
