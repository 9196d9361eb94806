//! dora node: writes frames as PNG, scores them against ground truth, summarises the run.
//!
//! Inputs: `ground_truth` (Frame, optional) and any number of frame inputs under other ids (one per
//! method). Writes `<out>/<method>/<seq>.png`, `<out>/metrics.csv` (a row per frame, flushed as it
//! goes) and, at the end, `<out>/summary.md` with the mean metrics per method and the frames
//! expected, written and missing on every input.

use dora_node_api::{DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_runtime::{Flow, Inputs, Link, Received, graph_inputs, receive, unix_now_ns};
use neuspike_schemas::meta::ORIGIN_UNIX_NS;
use neuspike_schemas::{Frame, Message, Parameter};
use neuspike_sink::{GROUND_TRUTH, InputTally, Sink, SinkConfig};

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-sink",
    about = "Writes and scores frames",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    sink: SinkConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens what the node needs, then runs its loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("sink")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let inputs: Vec<String> = graph_inputs(&node).into_iter().collect();
    run(node, events, &args.sink, &inputs)
}

/// Writes and scores every frame of `inputs` (`ground_truth` among them, when the graph has it).
fn run(
    node: DoraNode,
    events: EventStream,
    cfg: &SinkConfig,
    inputs: &[String],
) -> eyre::Result<()> {
    let has_gt = inputs.iter().any(|i| i == GROUND_TRUTH);
    let mut sink = Sink::new(cfg, has_gt).wrap_err("sink")?;
    let mut streams = Inputs::new(inputs);
    let mut link = Link::new(node, events)?;
    receive(&mut link, &mut streams, |_, msg| {
        match msg {
            Received::Message { input, meta, data } => {
                let f = Frame::from_arrow(meta, data)
                    .wrap_err_with(|| format!("sink: bad frame on input `{input}`"))?;
                if input == GROUND_TRUTH {
                    sink.on_truth(f)?;
                } else {
                    if let Some(Parameter::Integer(origin)) = meta.get(ORIGIN_UNIX_NS) {
                        let now = unix_now_ns();
                        sink.on_latency(input, now.saturating_sub(*origin), now);
                    }
                    sink.on_frame(input, f)?;
                }
            }
            Received::End {
                input: GROUND_TRUTH,
                ..
            } => sink.truth_ended()?,
            Received::End { .. } => {}
        }
        Ok(Flow::Continue)
    })?;
    let tallies = streams.iter().map(|(name, s)| {
        let tally = InputTally {
            announced: s.seq.announced(),
            received: s.seq.received(),
            missing: s.seq.missing(),
            ended: s.ended,
            cut: s.broken,
        };
        (name, tally)
    });
    let path = sink.finish(tallies)?;
    tracing::info!("summary written to {}", path.display());
    Ok(())
}

#[cfg(test)]
mod node_tests;
