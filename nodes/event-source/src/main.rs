//! dora node: the simulated DVS event camera. Output `events` (EventBatch), one batch per
//! `--batch-ns` interval, empty batches included, so a receiver always knows how far time went.

use dora_node_api::{DoraNode, Event, EventStream, StopCause};
use eyre::WrapErr;
use neuspike_event_source::{DvsConfig, EventCamera};
use neuspike_scene::Scene;
use neuspike_schemas::EventBatch;
use neuspike_schemas::node::{self, output, send, send_end};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-event-source",
    about = "Simulated DVS event camera",
    args_override_self = true
)]
struct Args {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow")]
    scene: String,
    /// Length of the interval each batch covers, nanoseconds.
    #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(i64).range(1..))]
    batch_ns: i64,
    /// Stop at this time (default: the scene's duration), nanoseconds.
    #[arg(long)]
    end_ns: Option<i64>,
    #[command(flatten)]
    camera: DvsConfig,
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("event-source")?;
    let scene = Scene::load(&args.scene).wrap_err("event-source: cannot load the scene")?;
    let camera = EventCamera::new(scene, args.camera.clone(), 0)?;
    let (node, events) = DoraNode::init_from_env()?;
    run(node, events, camera, &args)
}

fn run(
    mut node: DoraNode,
    mut events: EventStream,
    mut cam: EventCamera,
    args: &Args,
) -> eyre::Result<()> {
    let out = output("events");
    let end_ns = args.end_ns.unwrap_or_else(|| cam.scene().duration_ns());
    tracing::info!(end_ns, step_ns = cam.step_ns(), "event camera started");
    let mut seq = 0u64;
    let mut total = 0usize;
    while cam.time_ns() < end_ns {
        if let Ok(Event::Stop(StopCause::Manual)) = events.try_recv() {
            tracing::info!("stop requested");
            break;
        }
        let t_end = cam.time_ns().saturating_add(args.batch_ns).min(end_ns);
        let batch: EventBatch = cam.advance_to(t_end, seq);
        total += batch.len();
        send(&mut node, &out, &batch)?;
        seq += 1;
    }
    send_end::<EventBatch>(&mut node, &out, seq)?;
    tracing::info!(batches = seq, events = total, "event camera finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use neuspike_schemas::testing::{CannedInputs, output_ids, payload_len};

    #[test]
    fn batches_cover_time_and_end() {
        let args = Args::try_parse_from([
            "event-source",
            "--scene",
            "bright-fast",
            "--width",
            "34",
            "--height",
            "26",
            "--batch-ns",
            "1000000",
            "--end-ns",
            "3500000",
        ])
        .unwrap();
        let cam =
            EventCamera::new(Scene::load(&args.scene).unwrap(), args.camera.clone(), 0).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = CannedInputs::new(dir.path())
            .run(|node, events| run(node, events, cam, &args))
            .unwrap();
        // 3.5 ms in 1 ms batches: 4 batches and the marker.
        assert_eq!(output_ids(&out), vec!["events"; 5]);
        assert!(
            out[..4].iter().map(payload_len).sum::<usize>() > 0,
            "a fast scene makes events"
        );
        assert_eq!(payload_len(&out[4]), 0);
    }
}
