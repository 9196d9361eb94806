//! dora node: the spike camera, simulated or played from a recording. Output `spikes`
//! (SpikeChunk) and, when simulating and asked, or playing a recording with its ground truth,
//! `ground_truth` (Frame). The stage itself (the settings, the scene or the PKU `.dat` file, the
//! chunks and their ground truth) is `neuspike_spike_source::playback`.
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

use dora_node_api::{DoraNode, EventStream};
use neuspike_runtime::{Flow, Link, Pace, Pacer, Resume, produce};
use neuspike_schemas::{Frame, SpikeChunk};
use neuspike_spike_source::playback::{SpikeSource, SpikeSourceConfig};

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
    let source = open_source(&args)?;
    let (node, events) = neuspike_runtime::init_node()?;
    neuspike_runtime::run_on_rayon("spike-source", || run(node, events, source, &args))
}

/// Sends every chunk and its ground truth, then the end-of-stream markers, whatever happened.
fn run(
    node: DoraNode,
    events: EventStream,
    mut source: SpikeSource,
    args: &Args,
) -> eyre::Result<()> {
    let mut out = Link::new(node, events)?;
    out.declare::<SpikeChunk>("spikes");
    if source.sends_truth() {
        out.declare::<Frame>("ground_truth");
    }
    source.log_start();
    let resume = Resume::for_node(out.node())?;
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
    produce(&mut out, |out| {
        let Some(step) = source.next_step()? else {
            return Ok(Flow::Stop);
        };
        if let Some(due_unix_ns) = pacer.wait_until(step.due_ns) {
            out.set_origin(due_unix_ns);
        }
        out.send("spikes", &step.chunk)?;
        for frame in &step.truth {
            out.send("ground_truth", frame)?;
        }
        Ok(Flow::Continue)
    })?;
    resume.finished();
    Ok(source.finish()?)
}

#[cfg(test)]
mod node_tests;
