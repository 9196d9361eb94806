//! dora node: the DVS event camera, simulated or played from a recording. Output `events`
//! (EventBatch), one batch per `--batch-ns` interval, empty batches included, so a receiver always
//! knows how far time went. The stage itself (the settings, the scene or the recording, the
//! batches) is `neuspike_event_source::playback`.
//!
//! A recording that turns out bad part-way has every batch before the fault sent, then the
//! end-of-stream marker, and the node fails naming the file and the byte offset or line. A
//! relative `--file` is resolved against the node's working directory: under `neuspike run`
//! (dora), the graph's folder. `--pace realtime` sends each batch when the camera would have
//! finished it (wall clock from the node's start, camera clock from the stream's start); `--pace
//! fast` (default) sends as fast as the receivers take them.

use dora_node_api::{DoraNode, EventStream};
use neuspike_event_source::playback::{EventSource, EventSourceConfig};
use neuspike_runtime::{Flow, Link, Pace, Pacer, produce};
use neuspike_schemas::EventBatch;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-event-source",
    about = "DVS event camera: simulated, or played from a recording",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    source: EventSourceConfig,
    /// `fast`: send as fast as possible; `realtime`: send each batch when its interval has passed.
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
}

/// Checks the arguments and opens the scene or the file, before any message is sent.
fn open_source(args: &Args) -> eyre::Result<EventSource> {
    Ok(EventSource::open(&args.source)?)
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("event-source")?;
    let source = open_source(&args)?;
    let (node, events) = neuspike_runtime::init_node()?;
    neuspike_runtime::run_on_rayon("event-source", || run(node, events, source, &args))
}

/// Sends every batch, then the end-of-stream marker, whatever happened.
fn run(
    node: DoraNode,
    events: EventStream,
    mut source: EventSource,
    args: &Args,
) -> eyre::Result<()> {
    let mut out = Link::new(node, events)?;
    out.declare::<EventBatch>("events");
    source.log_start();
    let pacer = Pacer::start(args.pace);
    let played = produce(&mut out, |out| {
        let Some(step) = source.next_step()? else {
            return Ok(Flow::Stop);
        };
        if let Some(due_unix_ns) = pacer.wait_until(step.due_ns) {
            out.set_origin(due_unix_ns);
        }
        out.send("events", &step.batch)?;
        Ok(Flow::Continue)
    });
    source.log_end();
    played
}

#[cfg(test)]
mod node_tests;
