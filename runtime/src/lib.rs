//! What every neuspike dora node does the same way, so that a node's `main` holds only its
//! configuration:
//!
//! - [`run_stage`]: a stage (`neuspike_stage::Stage`) as a dora node, the node's whole body: its
//!   ports declared with their message types, its inputs decoded and handed over in order, what
//!   it sends sent with credits, its ends marked.
//! - [`receive`]: the receive loop. It moves each message's header out of dora's metadata,
//!   follows every input's sequence numbers (gaps and stale messages are logged and counted),
//!   takes the end-of-stream markers, and ends when every input the node reads has ended, never
//!   on dora's `InputClosed`/`Stop` (dora's scheduler may deliver those before an input's last
//!   messages).
//! - [`Link`]: the node's event stream and outputs. Outputs are declared with their message
//!   type; sending follows each output's sequence numbers, and [`Link::end_all`] sends every
//!   end-of-stream marker with its count.
//! - [`credit`]: lossless flow control over dora's zero-copy path. A consumer grants each input
//!   its queue's size and returns credits as it takes messages; a producer sends only while every
//!   consumer of the output has one, so no queue overflows and nothing is dropped or copied
//!   through the daemon. A graph turns it on per node (an output `credits`, read by producers).
//! - [`produce`]: a source's loop: it steps until the source is done or a stop is requested, and
//!   ends every output whatever happened, so the messages already sent stay a whole stream.
//! - logging ([`init_logging`]), configuration ([`parse_config`]), the rayon worker a node's loop
//!   runs on ([`run_on_rayon`]) and, in [`testing`], canned inputs that drive a node's `run`
//!   without a daemon. A source's pace ([`Pacer`]) and [`Flow`] are the stage crate's.
#![deny(missing_docs)]

pub mod credit;
mod inputs;
mod link;
mod metadata;
pub mod reorder;
mod resume;
mod stage;
pub mod testing;

pub use inputs::{InputState, Inputs, Received, receive};
pub use link::{Arrival, Link, RELAY_POLL, produce, relay, relay_remote};
pub use metadata::{meta_from_dora, meta_to_dora};
pub use neuspike_stage::{Flow, Pace, Pacer, unix_now_ns};
pub use resume::Resume;
pub use stage::run_stage;

use std::collections::BTreeSet;

use dora_node_api::DoraNode;
use eyre::WrapErr;

/// The log filter when `RUST_LOG` is unset: our nodes at `info`, dora's node API at `error` (its
/// per-message transport diagnostics are warnings).
pub const DEFAULT_LOG_FILTER: &str = "info,dora_node_api=error,zenoh=error";

/// Logs to standard error through `tracing`, at the level `RUST_LOG` gives (default
/// [`DEFAULT_LOG_FILTER`]); colours only on a terminal (under dora, stderr is a pipe).
pub fn init_logging() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(DEFAULT_LOG_FILTER));
    // A second call (tests) keeps the first subscriber.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .without_time()
        .try_init();
}

/// A node's exit: success, or its error logged as one line (what went wrong and its causes, no
/// source locations or backtrace) and a failure status.
pub fn exit_code(result: eyre::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// Parses a node's configuration from the graph's `args:` (the node's command-line arguments).
/// A wrong key or value is an error naming the key and the value, returned before any message is
/// sent.
pub fn parse_config<C: clap::Parser>(node: &str) -> eyre::Result<C> {
    C::try_parse().map_err(|e| eyre::eyre!("{node}: bad configuration in the graph's `args:`: {e}"))
}

/// The zenoh settings a neuspike node's session gets unless `DORA_ZENOH_CONFIG_OVERLAY` names
/// the user's own file. dora publishes on zenoh with `CongestionControl::Drop`: a message that
/// finds the link's 2 real-time batches busy for 1 ms is dropped, which a loaded machine does
/// often. With credits bounding what is in flight, a queue of 16 batches and a wait of up to 1 s
/// before dropping makes that path lossless in practice (and a loss that still happens is a gap
/// in the sequence numbers, counted and logged).
pub const ZENOH_OVERLAY: &str = "{ transport: { link: { tx: { queue: { size: { real_time: 16 }, \
     congestion_control: { drop: { wait_before_drop: 1000000 } } } } } } }";

/// Connects to the dora daemon (`DoraNode::init_from_env`) with the [`ZENOH_OVERLAY`] settings.
/// Call it first in `main`, before any thread starts.
///
/// # Errors
/// The overlay file could not be written, or dora could not connect.
pub fn init_node() -> eyre::Result<(DoraNode, dora_node_api::EventStream)> {
    const OVERLAY_ENV: &str = "DORA_ZENOH_CONFIG_OVERLAY";
    let _overlay = if std::env::var_os(OVERLAY_ENV).is_none() {
        use std::io::Write;
        let mut file = tempfile::Builder::new()
            .prefix("neuspike-zenoh-")
            .suffix(".json5")
            .tempfile()
            .wrap_err("cannot write the zenoh settings to a temporary file")?;
        file.write_all(ZENOH_OVERLAY.as_bytes())
            .wrap_err("cannot write the zenoh settings to a temporary file")?;
        // SAFETY: called at the start of a node's `main`, before it starts any thread, so
        // nothing reads the environment concurrently. dora reads the setting only from there.
        #[allow(unsafe_code)]
        unsafe {
            std::env::set_var(OVERLAY_ENV, file.path())
        };
        Some(file)
    } else {
        None
    };
    // The file is read while the session opens, inside `init_from_env`; dropped after.
    DoraNode::init_from_env().map_err(|e| eyre::eyre!("cannot connect to the dora daemon: {e}"))
}

/// Runs a node's loop `f` on a worker of a new rayon pool (one thread per core), so that the
/// parallel part of every kernel the loop calls (the scene renderer, the event kernels, the
/// filters) starts on the calling thread. Called from outside a pool, each parallel call waits
/// for a sleeping worker to pick it up: 55 us a call here (`bench_spike`: a 100-us kernel run
/// through a one-thread pool's `install` against called directly).
pub fn run_on_rayon<R: Send>(
    node: &str,
    f: impl FnOnce() -> eyre::Result<R> + Send,
) -> eyre::Result<R> {
    rayon::ThreadPoolBuilder::new()
        .thread_name({
            let node = node.to_string();
            move |i| format!("{node}-{i}")
        })
        .build()
        .wrap_err_with(|| format!("{node}: could not start its thread pool"))?
        .install(f)
}

/// The ids of the data inputs the graph gives `node` (none under the test harness): its
/// consumers' credits, which the [`Link`] takes, are not among them.
pub fn graph_inputs(node: &DoraNode) -> BTreeSet<String> {
    let credits = link::credit_inputs(node);
    node.node_config()
        .inputs
        .keys()
        .map(|k| k.to_string())
        .filter(|k| !credits.contains(k))
        .collect()
}

/// The ids of the data outputs the graph declares for `node` (none under the test harness): the
/// `credits` output, which the [`Link`] sends on, is not among them.
pub fn graph_outputs(node: &DoraNode) -> BTreeSet<String> {
    node.node_config()
        .outputs
        .iter()
        .map(|k| k.to_string())
        .filter(|k| k != credit::CREDITS)
        .collect()
}
