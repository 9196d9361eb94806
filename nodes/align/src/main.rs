//! dora node: aligns the spike and event streams. Inputs `spikes` (SpikeChunk) and, optionally,
//! `events` (EventBatch); output `windows` (AlignedWindow) and, when the graph declares it,
//! `events` (EventBatch): the event stream on the spike clock cut at every window's reference
//! instant, each event once (what the event filters of `infer` take).

use dora_node_api::{DoraNode, EventStream};
use neuspike_align::{AlignConfig, Aligner};
use neuspike_runtime::{Flow, Inputs, Link, Received, graph_inputs, graph_outputs, receive};
use neuspike_schemas::{AlignedWindow, EventBatch, Message, SpikeChunk};

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

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("align")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let mut aligner = Aligner::new(args.align, graph_inputs(&node).contains("events"));
    if graph_outputs(&node).contains("events") {
        aligner = aligner.with_event_stream();
    }
    run(node, events, aligner)
}

/// Sends every ready window, each followed by its batch of the event stream (if wanted).
fn send_ready(out: &mut Link, aligner: &mut Aligner) -> eyre::Result<()> {
    while let Some(window) = aligner.pop_ready() {
        out.send("windows", &window)?;
        if let Some(batch) = aligner.pop_stream() {
            out.send("events", &batch)?;
        }
    }
    Ok(())
}

fn run(node: DoraNode, events: EventStream, mut aligner: Aligner) -> eyre::Result<()> {
    let mut out = Link::new(node, events)?;
    out.declare::<AlignedWindow>("windows");
    if aligner.streams_events() {
        out.declare::<EventBatch>("events");
    }
    let mut inputs = Inputs::new(["spikes", "events"]);
    receive(&mut out, &mut inputs, |out, msg| {
        match msg {
            Received::Message {
                input: "spikes",
                meta,
                data,
            } => aligner.push_spikes(SpikeChunk::from_arrow(meta, data)?)?,
            Received::Message { meta, data, .. } => {
                aligner.push_events(EventBatch::from_arrow(meta, data)?)
            }
            Received::End {
                input: "spikes", ..
            } => aligner.close_spikes(),
            Received::End { .. } => aligner.close_events(),
        }
        if let Some(e) = aligner.take_rig_error() {
            return Err(e.into());
        }
        send_ready(out, &mut aligner)?;
        Ok(if aligner.finished() {
            Flow::Stop
        } else {
            Flow::Continue
        })
    })?;
    aligner.close_spikes();
    aligner.close_events();
    if let Some(e) = aligner.take_rig_error() {
        return Err(e.into());
    }
    send_ready(&mut out, &mut aligner)?;
    // Windows skipped for missing planes count as sent-and-lost: the markers cover them.
    out.at_least("windows", aligner.next_seq())?;
    if aligner.streams_events() {
        out.at_least("events", aligner.next_seq())?;
    }
    out.end_all()?;
    tracing::info!(
        windows = aligner.emitted(),
        skipped = aligner.skipped_windows(),
        spike_chunks_lost = inputs.get("spikes").map_or(0, |s| s.seq.missing()),
        event_batches_lost = inputs.get("events").map_or(0, |s| s.seq.missing()),
        events_outside_the_spike_grid = aligner.dropped_events(),
        "align finished"
    );
    Ok(())
}

#[cfg(test)]
mod node_tests;
