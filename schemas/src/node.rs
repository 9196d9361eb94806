//! What every neuspike node does the same way: logging, sending messages, ending streams,
//! reading its configuration from the graph.

use dora_node_api::dora_core::config::DataId;
use dora_node_api::{DoraArray, DoraNode};
use eyre::WrapErr;

use crate::stream::end_of_stream;
use crate::Message;

/// Logs to standard error through `tracing`, at the level `RUST_LOG` gives (default `info`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // A second call (tests) keeps the first subscriber.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}

/// Parses a node's configuration from the graph's `args:` (the node's command-line arguments).
/// A wrong key or value is an error naming the key and the value, returned before any message is
/// sent.
pub fn parse_config<C: clap::Parser>(node: &str) -> eyre::Result<C> {
    C::try_parse().map_err(|e| eyre::eyre!("{node}: bad configuration in the graph's `args:`: {e}"))
}

/// Sends one message on an output.
pub fn send<M: Message>(node: &mut DoraNode, output: &DataId, msg: &M) -> eyre::Result<()> {
    let (meta, data) = msg.to_arrow();
    node.send_output(output.clone(), meta, DoraArray::from(data))
        .wrap_err_with(|| format!("failed to send on output `{output}`"))
}

/// Ends an output that sent `count` messages.
pub fn send_end<M: Message>(node: &mut DoraNode, output: &DataId, count: u64) -> eyre::Result<()> {
    let (meta, data) = end_of_stream::<M>(count);
    node.send_output(output.clone(), meta, DoraArray::from(data))
        .wrap_err_with(|| format!("failed to end output `{output}`"))
}

/// An output id from a static name.
pub fn output(name: &str) -> DataId {
    DataId::from(name.to_string())
}
