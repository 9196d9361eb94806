//! dora node: publishes every input on zenoh as neuspike's own message (Arrow IPC on
//! `neuspike/<graph>/<input>`), and the frame inputs named with `--ros2` as ROS 2
//! `sensor_msgs/msg/Image` on rmw_zenoh's keys. The stage itself is `neuspike_publish`.

use std::collections::BTreeMap;

use dora_node_api::{DoraNode, EventStream};
use neuspike_publish::{PublishConfig, Publisher};
use neuspike_runtime::{Flow, Inputs, Link, Received, graph_inputs, receive, unix_now_ns};
use neuspike_schemas::arrow::array::new_empty_array;
use neuspike_schemas::arrow::datatypes::DataType;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-publish",
    about = "Publishes a graph's messages on zenoh and ROS 2",
    args_override_self = true
)]
struct Args {
    #[command(flatten)]
    publish: PublishConfig,
}

fn main() -> std::process::ExitCode {
    neuspike_runtime::exit_code(start())
}

/// Reads the settings, opens the zenoh session, then runs the loop.
fn start() -> eyre::Result<()> {
    neuspike_runtime::init_logging();
    let args: Args = neuspike_runtime::parse_config("publish")?;
    let (node, events) = neuspike_runtime::init_node()?;
    let inputs: Vec<String> = graph_inputs(&node).into_iter().collect();
    let publisher = Publisher::open(&args.publish, &inputs)?;
    run(node, events, publisher, &inputs)
}

/// The message type each input declares in the graph (`input_types`); `unknown` without one.
fn input_types(node: &DoraNode, inputs: &[String]) -> BTreeMap<String, String> {
    let declared = node.dataflow_descriptor().ok().and_then(|d| {
        d.nodes
            .iter()
            .find(|n| n.id == *node.id())
            .map(|n| n.input_types.clone())
    });
    inputs
        .iter()
        .map(|i| {
            let urn = declared
                .as_ref()
                .and_then(|t| t.iter().find(|(k, _)| AsRef::<str>::as_ref(*k) == i))
                .map_or_else(|| "unknown".to_string(), |(_, v)| v.clone());
            (i.clone(), urn)
        })
        .collect()
}

/// Publishes every message of `inputs`, end-of-stream markers included, in order.
fn run(
    node: DoraNode,
    events: EventStream,
    mut publisher: Publisher,
    inputs: &[String],
) -> eyre::Result<()> {
    let types = input_types(&node, inputs);
    let mut streams = Inputs::new(inputs);
    let mut link = Link::new(node, events)?;
    let received = receive(&mut link, &mut streams, |_, msg| {
        match msg {
            Received::Message { input, meta, data } => {
                let urn = types.get(input).map_or("unknown", String::as_str);
                publisher.publish(input, urn, meta, data, unix_now_ns())?;
            }
            Received::End { input, count } => {
                let urn = types.get(input).map_or("unknown", String::as_str);
                let meta = neuspike_schemas::end_of_stream_header(count);
                let data = new_empty_array(&DataType::Null);
                publisher.publish(input, urn, &meta, &data, unix_now_ns())?;
            }
        }
        Ok(Flow::Continue)
    });
    // The bag is finished whatever happened: what was recorded stays readable.
    let finished = publisher.finish();
    received?;
    finished?;
    tracing::info!(
        published = publisher.published(),
        lost = streams.missing(),
        zid = %publisher.zid(),
        "publish finished"
    );
    Ok(())
}

#[cfg(test)]
mod node_tests;
