//! dora node: the simulated spike camera. Outputs `spikes` (SpikeChunk) and, when asked,
//! `ground_truth` (Frame) at every `--gt-every-planes`-th plane.

use dora_node_api::{DoraNode, Event, EventStream, StopCause};
use eyre::WrapErr;
use neuspike_scene::Scene;
use neuspike_schemas::node::{self, output, send, send_end};
use neuspike_schemas::{Frame, FrameKind, SpikeChunk};
use neuspike_spike_source::{CameraConfig, SpikeCamera};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-spike-source",
    about = "Simulated spike camera",
    args_override_self = true
)]
struct Args {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow")]
    scene: String,
    /// Planes per output message.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    chunk_planes: u32,
    /// Emit the ground-truth frame at every plane whose index is a multiple of this (0 = never).
    #[arg(long, default_value_t = 0)]
    gt_every_planes: u64,
    /// Stop after this many planes (default: the scene's duration).
    #[arg(long)]
    max_planes: Option<u64>,
    #[command(flatten)]
    camera: CameraConfig,
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("spike-source")?;
    let scene = Scene::load(&args.scene).wrap_err("spike-source: cannot load the scene")?;
    let camera = SpikeCamera::new(scene, args.camera.clone())?;
    let (node, events) = DoraNode::init_from_env()?;
    run(node, events, camera, &args)
}

fn run(
    mut node: DoraNode,
    mut events: EventStream,
    mut cam: SpikeCamera,
    args: &Args,
) -> eyre::Result<()> {
    let spikes = output("spikes");
    let gt_out = output("ground_truth");
    let total = args.max_planes.unwrap_or_else(|| cam.total_planes());
    tracing::info!(
        planes = total,
        period_ns = cam.period_ns(),
        render_step = cam.render_step(),
        "spike camera started"
    );
    let (mut seq, mut gt_seq) = (0u64, 0u64);
    while cam.tick() < total {
        match events.try_recv() {
            Ok(Event::Stop(StopCause::Manual)) => {
                tracing::info!("stop requested");
                break;
            }
            Ok(other) => tracing::debug!(?other, "ignored event"),
            Err(_) => {}
        }
        let n = (total - cam.tick()).min(u64::from(args.chunk_planes)) as usize;
        let first = cam.tick();
        let chunk: SpikeChunk = cam.next_chunk(n, seq);
        send(&mut node, &spikes, &chunk)?;
        seq += 1;
        if args.gt_every_planes > 0 {
            let step = args.gt_every_planes;
            let mut k = first.div_ceil(step) * step;
            while k < first + n as u64 {
                let frame = Frame {
                    kind: FrameKind::GroundTruth,
                    method: "ground-truth".into(),
                    t_ref_ns: cam.plane_time_ns(k),
                    compute_ns: 0,
                    seq: gt_seq,
                    data: cam.ground_truth(k),
                };
                send(&mut node, &gt_out, &frame)?;
                gt_seq += 1;
                k += step;
            }
        }
    }
    send_end::<SpikeChunk>(&mut node, &spikes, seq)?;
    if args.gt_every_planes > 0 {
        send_end::<Frame>(&mut node, &gt_out, gt_seq)?;
    }
    tracing::info!(chunks = seq, ground_truth = gt_seq, "spike camera finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use neuspike_schemas::testing::{CannedInputs, output_ids, payload_len};

    #[test]
    fn chunks_ground_truth_and_end_markers() {
        let args = Args::try_parse_from([
            "spike-source",
            "--scene",
            "bright-static",
            "--width",
            "40",
            "--height",
            "25",
            "--chunk-planes",
            "20",
            "--gt-every-planes",
            "20",
            "--max-planes",
            "50",
        ])
        .unwrap();
        let cam = SpikeCamera::new(Scene::load(&args.scene).unwrap(), args.camera.clone()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = CannedInputs::new(dir.path())
            .run(|node, events| run(node, events, cam, &args))
            .unwrap();
        let ids = output_ids(&out);
        // 50 planes: chunks of 20, 20, 10; truth at planes 0, 20, 40.
        assert_eq!(ids.iter().filter(|i| *i == "spikes").count(), 4);
        assert_eq!(ids.iter().filter(|i| *i == "ground_truth").count(), 4);
        let spikes: Vec<usize> = out
            .iter()
            .filter(|o| o["id"] == "spikes")
            .map(payload_len)
            .collect();
        let per = neuspike_schemas::bytes_per_plane(40, 25);
        assert_eq!(spikes, vec![20 * per, 20 * per, 10 * per, 0]);
    }

    #[test]
    fn a_wrong_key_is_named() {
        let e = Args::try_parse_from(["spike-source", "--rate-hz", "fast"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("rate-hz") && e.contains("fast"), "{e}");
        let e = Args::try_parse_from(["spike-source", "--sceen", "x"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--sceen"), "{e}");
    }
}
