//! What every neuspike dora node does the same way, so that a node's `run` holds only its own
//! logic:
//!
//! - [`receive`]: the receive loop. It moves each message's header out of dora's metadata,
//!   follows every input's sequence numbers (gaps and stale messages are logged and counted),
//!   takes the end-of-stream markers, and ends when every input the node reads has ended, never
//!   on dora's `InputClosed`/`Stop` (dora's scheduler may deliver those before an input's last
//!   messages).
//! - [`Outputs`]: the node's outputs, declared with their message type; sending follows each
//!   output's sequence numbers, and [`Outputs::end_all`] sends every end-of-stream marker with
//!   its count.
//! - [`produce`]: a source's loop: it steps until the source is done or a stop is requested, and
//!   ends every output whatever happened, so the messages already sent stay a whole stream.
//! - logging ([`init_logging`]), configuration ([`parse_config`]), the rayon worker a node's loop
//!   runs on ([`run_on_rayon`]), a source's pace ([`Pacer`]) and, in [`testing`], canned inputs
//!   that drive a node's `run` without a daemon.
#![deny(missing_docs)]

mod inputs;
mod metadata;
mod outputs;
pub mod testing;

pub use inputs::{Flow, InputState, Inputs, Received, receive};
pub use metadata::{meta_from_dora, meta_to_dora};
pub use outputs::{Outputs, produce};

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use dora_node_api::{DoraNode, Event, EventStream, StopCause};
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

/// The ids of the inputs the graph gives `node` (none under the test harness).
pub fn graph_inputs(node: &DoraNode) -> BTreeSet<String> {
    node.node_config()
        .inputs
        .keys()
        .map(|k| k.to_string())
        .collect()
}

/// The ids of the outputs the graph declares for `node` (none under the test harness).
pub fn graph_outputs(node: &DoraNode) -> BTreeSet<String> {
    node.node_config()
        .outputs
        .iter()
        .map(|k| k.to_string())
        .collect()
}

/// How fast a source sends its messages.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Pace {
    /// As fast as the receivers take them.
    #[default]
    Fast,
    /// On the camera's clock: a message leaves when the camera time it covers has passed.
    Realtime,
}

/// Holds a source's messages back to the camera's clock under [`Pace::Realtime`].
#[derive(Clone, Copy, Debug)]
pub struct Pacer {
    pace: Pace,
    start: Instant,
}

impl Pacer {
    /// A clock starting now.
    pub fn start(pace: Pace) -> Self {
        Pacer {
            pace,
            start: Instant::now(),
        }
    }

    /// Waits until `stream_ns` of camera time have passed since the start (no wait when fast;
    /// a negative time is due at once).
    pub fn wait_until(&self, stream_ns: i64) {
        if self.pace == Pace::Realtime {
            let due = self.start + Duration::from_nanos(u64::try_from(stream_ns).unwrap_or(0));
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
    }
}

/// Whether a source was asked to stop (a source has no inputs, so only a manual stop counts);
/// never blocks.
pub fn stop_requested(events: &mut EventStream) -> bool {
    match events.try_recv() {
        Ok(Event::Stop(StopCause::Manual)) => {
            tracing::info!("stop requested");
            true
        }
        Ok(other) => {
            tracing::debug!(?other, "ignored event");
            false
        }
        Err(_) => false,
    }
}
