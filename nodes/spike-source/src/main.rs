//! dora node: the spike camera, simulated or played from a recording. Output `spikes`
//! (SpikeChunk) and, when simulating and asked, or playing a recording with its ground truth,
//! `ground_truth` (Frame). The stage itself (the settings, the scene or the PKU `.dat` file, the
//! chunks and their ground truth) is `neuspike_spike_camera::playback`.
//!
//! A relative `--file` is resolved against the node's working directory: under `neuspike run`
//! (dora), the graph's folder. The chunks of a recording carry `lum_per_rate` = `--lum-per-rate`,
//! default 1.0: a recording states no calibration, and with 1.0 a TFP frame is the firing rate
//! itself. `--pace realtime` sends each chunk when its last plane would have been read out by the
//! camera (plane rate `--rate-hz`, wall clock from the node's start); `--pace fast` (default)
//! sends as fast as the receivers take them.
//!
//! Restarted by dora (`restart_policy: on-failure` in the graph), a paced source resumes where
//! its camera is now, on its first start's clock, and numbers its chunks as if it had sent the
//! planes it missed: its consumers count them as a gap. A fast source cannot tell where it
//! stopped, and a restart of one fails with an error saying so.
//!
//! Or the camera is on another machine: `--from-zenoh KEY` relays the SpikeChunks it publishes
//! (`neuspike publish-file`, a graph's publish node), a chunk lost on the way counted by its
//! sequence number and passed on as a gap.

use std::time::Duration;

use dora_node_api::{DoraNode, EventStream};
use neuspike_net::{Remote, ZenohArgs};
use neuspike_runtime::{Link, Pace, Pacer, Resume, relay_remote};
use neuspike_schemas::{Message, SpikeChunk};
use neuspike_spike_camera::playback::{SpikeSource, SpikeSourceConfig, SpikeSourceStage};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-spike-source",
    about = "Spike camera: simulated, or played from a PKU .dat recording",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    source: SpikeSourceConfig,
    /// `fast`: send as fast as possible; `realtime`: send at the plane rate `--rate-hz`.
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
    /// Take the planes from this zenoh key instead of a scene or a file: SpikeChunk messages
    /// (Arrow IPC) as another machine publishes them, e.g. `neuspike/camera/spikes`.
    #[arg(long, value_name = "KEY", conflicts_with_all = ["file", "gt_every_planes"])]
    from_zenoh: Option<String>,
    /// Seconds without a message from `--from-zenoh` before the source gives up (before its
    /// first message, or before the stream's end-of-stream marker).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    silence_s: u64,
    /// The zenoh session of `--from-zenoh`.
    #[command(flatten)]
    zenoh: ZenohArgs,
}

/// Checks the arguments and opens the scene or the file, before any message is sent.
fn open_source(args: &Args) -> eyre::Result<SpikeSource> {
    Ok(SpikeSource::open(&args.source)?)
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("spike-source")?;
    if let Some(key) = &args.from_zenoh {
        if args.pace != Pace::Fast {
            eyre::bail!(
                "spike-source: --pace {:?} with --from-zenoh: the camera sets the pace",
                args.pace
            );
        }
        let (node, events) = neuspike_runtime::init_node()?;
        return run_remote(node, events, key, &args);
    }
    let source = open_source(&args)?;
    let (node, events) = neuspike_runtime::init_node()?;
    neuspike_runtime::run_on_rayon("spike-source", || run(node, events, source, &args))
}

/// Relays the planes another machine publishes on `key`, lost chunks counted by their sequence
/// numbers (and seen downstream as gaps), until the stream's end-of-stream marker.
fn run_remote(node: DoraNode, events: EventStream, key: &str, args: &Args) -> eyre::Result<()> {
    let session = args.zenoh.open()?;
    let mut out = Link::new(node, events)?;
    out.declare::<SpikeChunk>("spikes");
    let silence = Duration::from_secs(args.silence_s);
    let mut remote = Remote::subscribe(&session, key, SpikeChunk::TYPE_URN, silence)?
        .rejoining_after(args.zenoh.rejoin_after()?);
    tracing::info!(key, "waiting for spike chunks");
    relay_remote::<SpikeChunk>(&mut out, "spikes", &mut remote)
}

/// Sends every chunk and its ground truth, then the end-of-stream markers, whatever happened.
fn run(
    node: DoraNode,
    events: EventStream,
    mut source: SpikeSource,
    args: &Args,
) -> eyre::Result<()> {
    source.log_start();
    let resume = Resume::for_node(&node)?;
    let pacer = Pacer::started_at(args.pace, resume.first_start_unix_ns);
    if resume.restarted {
        if args.pace != Pace::Realtime {
            eyre::bail!(
                "spike-source was restarted, and with --pace fast it cannot tell where its stream stopped: a source that dora restarts must run with --pace realtime"
            );
        }
        let plane = pacer.elapsed_ns() / args.source.camera.validate()?;
        let first = source.skip_to(u64::try_from(plane).unwrap_or(0))?;
        tracing::warn!(
            first_plane = first,
            "restarted: resuming on the first start's clock; the planes missed are a gap"
        );
    }
    neuspike_runtime::run_stage(node, events, &mut SpikeSourceStage::new(source, pacer))?;
    resume.finished();
    Ok(())
}

#[cfg(test)]
mod node_tests;
