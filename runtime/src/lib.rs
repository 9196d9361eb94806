//! What every neuspike dora node does the same way, so that a node's `run` holds only its own
//! logic:
//!
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
//!   runs on ([`run_on_rayon`]), a source's pace ([`Pacer`]) and, in [`testing`], canned inputs
//!   that drive a node's `run` without a daemon.
#![deny(missing_docs)]

pub mod credit;
mod inputs;
mod link;
mod metadata;
pub mod reorder;
mod resume;
pub mod testing;

pub use inputs::{Flow, InputState, Inputs, Received, receive};
pub use link::{Arrival, Link, RELAY_POLL, produce, relay, relay_remote, unix_now_ns};
pub use metadata::{meta_from_dora, meta_to_dora};
pub use resume::Resume;

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

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
    start_unix_ns: i64,
}

impl Pacer {
    /// A clock starting now.
    pub fn start(pace: Pace) -> Self {
        Pacer {
            pace,
            start: Instant::now(),
            start_unix_ns: unix_now_ns(),
        }
    }

    /// A clock that started at `start_unix_ns` (ns since the epoch; a later time counts as now):
    /// a restarted source's, on its first start's clock ([`Resume`]).
    pub fn started_at(pace: Pace, start_unix_ns: i64) -> Self {
        let now = Instant::now();
        let now_unix = unix_now_ns();
        let ago = u64::try_from(now_unix.saturating_sub(start_unix_ns)).unwrap_or(0);
        let start = now.checked_sub(Duration::from_nanos(ago)).unwrap_or(now);
        Pacer {
            pace,
            start,
            start_unix_ns: start_unix_ns.min(now_unix),
        }
    }

    /// Camera time since the clock's start, ns (0 when not paced: a fast source has no clock).
    pub fn elapsed_ns(&self) -> i64 {
        match self.pace {
            Pace::Realtime => i64::try_from(self.start.elapsed().as_nanos()).unwrap_or(i64::MAX),
            Pace::Fast => 0,
        }
    }

    /// Waits until `stream_ns` of camera time have passed since the start (no wait when fast;
    /// a negative time is due at once). Under [`Pace::Realtime`], returns the wall time (ns since
    /// the epoch) at which a camera would have delivered that data: a source that has fallen
    /// behind stamps it as its messages' origin ([`Link::set_origin`]), so their latency counts
    /// the time they waited, as a real camera's buffer would hold them.
    pub fn wait_until(&self, stream_ns: i64) -> Option<i64> {
        if self.pace != Pace::Realtime {
            return None;
        }
        let stream_ns = stream_ns.max(0);
        let due = self.start + Duration::from_nanos(stream_ns as u64);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        Some(self.start_unix_ns.saturating_add(stream_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_paced_source_learns_when_the_camera_would_have_delivered_its_data() {
        assert_eq!(Pacer::start(Pace::Fast).wait_until(1_000_000_000), None);
        let before = unix_now_ns();
        let p = Pacer::start(Pace::Realtime);
        let start = Instant::now();
        // Due 2 ms after the start: waited for, and stamped 2 ms after the start.
        let due = p.wait_until(2_000_000).expect("paced");
        assert!(start.elapsed() >= Duration::from_millis(2));
        assert!(due >= before + 2_000_000 && due <= unix_now_ns(), "{due}");
        // Past data is due at once, stamped when it was due (a negative time at the start).
        let t = Instant::now();
        assert_eq!(p.wait_until(1_000_000), Some(due - 1_000_000));
        assert_eq!(p.wait_until(-5), Some(due - 2_000_000));
        assert!(t.elapsed() < Duration::from_millis(50));
        // A restarted source's clock runs from its first start.
        let earlier = Pacer::started_at(Pace::Realtime, unix_now_ns() - 3_000_000_000);
        let e = earlier.elapsed_ns();
        assert!((3_000_000_000..3_100_000_000).contains(&e), "{e}");
        assert_eq!(Pacer::started_at(Pace::Fast, 0).elapsed_ns(), 0);
    }
}
