//! `neuspike publish-file`: a recording played onto zenoh as a camera machine would send it, for
//! a graph elsewhere whose source takes a zenoh key (`spike-source --from-zenoh KEY`,
//! `event-source --from-zenoh KEY`).
//!
//! The recording is played by the same code as the source nodes' playback (a PKU `.dat` as
//! SpikeChunks, an event file as EventBatches, chunked as the node would), each message sent as
//! Arrow IPC (`neuspike_schemas::ipc`) with its sequence number and `origin_unix_ns`, then the
//! end-of-stream marker with the count. zenoh keeps nothing for late subscribers, so it waits
//! for one before the first message, and it sends with congestion control `block`: a slow
//! receiver holds it back instead of losing messages. After the end-of-stream marker it waits
//! for its subscribers to leave (they do once they have taken the marker), since closing the
//! session drops what is still queued on the link.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::Parser;
use eyre::{WrapErr, bail, eyre};
use neuspike_event_camera::playback::{EventSource, EventSourceConfig};
use neuspike_net::ZenohArgs;
use neuspike_runtime::{Pace, Pacer, unix_now_ns};
use neuspike_schemas::meta::ORIGIN_UNIX_NS;
use neuspike_schemas::{EventBatch, Message, MetaExt, SpikeChunk, end_of_stream, ipc};
use neuspike_spike_camera::playback::{SpikeSource, SpikeSourceConfig};
use zenoh::Wait;

/// `neuspike publish-file`'s settings.
#[derive(Debug, clap::Args)]
pub struct PublishFile {
    /// The recording: a PKU spike `.dat`, or an event file (ECD text, Prophesee RAW or DAT,
    /// AEDAT 4).
    pub file: PathBuf,
    /// The zenoh key (default `neuspike/camera/spikes` for spikes, `neuspike/camera/events` for
    /// events).
    #[arg(long)]
    pub key: Option<String>,
    /// The source node's arguments for the recording, as a graph's `args:` would give them, e.g.
    /// `--args "--chunk-planes 40 --rate-hz 40000"` or `--args "--batch-ns 500000"`.
    #[arg(long, default_value = "", allow_hyphen_values = true)]
    pub args: String,
    /// `realtime` (default): each message leaves when the camera would have finished it;
    /// `fast`: as fast as the receiver takes them.
    #[arg(long, value_enum, default_value_t = Pace::Realtime)]
    pub pace: Pace,
    /// Seconds to wait for a subscriber before the first message, and for the subscribers to
    /// take the end of the stream and leave before closing.
    #[arg(long, default_value_t = 30)]
    pub wait_s: u64,
    /// The zenoh session.
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

#[derive(Debug, clap::Parser)]
#[command(no_binary_name = true, args_override_self = true)]
struct SpikeArgs {
    #[command(flatten)]
    cfg: SpikeSourceConfig,
}

#[derive(Debug, clap::Parser)]
#[command(no_binary_name = true, args_override_self = true)]
struct EventArgs {
    #[command(flatten)]
    cfg: EventSourceConfig,
}

/// What was published.
#[derive(Debug)]
pub struct Published {
    /// The key.
    pub key: String,
    /// Messages, the end-of-stream marker not counted.
    pub messages: u64,
    /// Planes (spikes) or events in them.
    pub items: u64,
    /// Whether they were spike chunks (else event batches).
    pub spikes: bool,
    /// Wall time from the first message to the marker.
    pub elapsed: Duration,
}

fn source_args(file: &Path, extra: &str) -> Vec<String> {
    let mut v = vec!["--file".to_string(), file.display().to_string()];
    v.extend(extra.split_whitespace().map(str::to_string));
    v
}

/// Plays the recording onto zenoh.
///
/// # Errors
/// The recording cannot be opened or read (after the messages before the fault, and the marker,
/// flagged cut), the source arguments are wrong, the session cannot open, or nobody subscribes
/// within `--wait-s`.
pub fn run(opts: &PublishFile) -> eyre::Result<Published> {
    let format = neuspike_formats::sniff(&opts.file)
        .wrap_err_with(|| format!("{}: cannot tell its format", opts.file.display()))?;
    let spikes = matches!(format, neuspike_formats::Format::PkuSpikes);
    let key = opts.key.clone().unwrap_or_else(|| {
        if spikes {
            "neuspike/camera/spikes".into()
        } else {
            "neuspike/camera/events".into()
        }
    });
    let args = source_args(&opts.file, &opts.args);
    let mut next: Box<NextStep> = if spikes {
        let a = SpikeArgs::try_parse_from(&args)
            .map_err(|e| eyre!("--args: not spike-source arguments: {e}"))?;
        let mut source = SpikeSource::open(&a.cfg)?;
        Box::new(move || {
            Ok(source
                .next_step()?
                .map(|s| (Step::Spikes(s.chunk), s.due_ns)))
        })
    } else {
        let a = EventArgs::try_parse_from(&args)
            .map_err(|e| eyre!("--args: not event-source arguments: {e}"))?;
        let mut source = EventSource::open(&a.cfg)?;
        Box::new(move || {
            Ok(source
                .next_step()?
                .map(|s| (Step::Events(s.batch), s.due_ns)))
        })
    };

    let session = opts.zenoh.open()?;
    let publisher = session
        .declare_publisher(key.clone())
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .reliability(zenoh::qos::Reliability::Reliable)
        .wait()
        .map_err(|e| eyre!("cannot publish on {key}: {e}"))?;
    let deadline = Instant::now() + Duration::from_secs(opts.wait_s);
    loop {
        let matched = publisher
            .matching_status()
            .wait()
            .map_err(|e| eyre!("{key}: {e}"))?
            .matching();
        if matched {
            break;
        }
        if Instant::now() >= deadline {
            bail!(
                "{key}: no subscriber in {} s (start the graph that reads it first, and check --connect/--listen)",
                opts.wait_s
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // The subscriber's declaration arrived; give its route a moment to settle on every hop.
    std::thread::sleep(Duration::from_millis(200));

    let sent = std::cell::Cell::new(0u32);
    let put = |urn: &str,
               meta: &neuspike_schemas::Meta,
               data: &neuspike_schemas::arrow::array::ArrayRef|
     -> eyre::Result<()> {
        let bytes = ipc::encode(urn, meta, data)?;
        let sn = sent.get();
        sent.set(sn.wrapping_add(1));
        neuspike_net::put_message(&publisher, bytes, sn).map_err(|e| eyre!("{key}: {e}"))
    };
    let pacer = Pacer::start(opts.pace);
    let start = Instant::now();
    let (mut messages, mut items, mut count, mut urn) = (0u64, 0u64, 0u64, "");
    let played: eyre::Result<()> = (|| {
        while let Some((step, due_ns)) = next()? {
            let origin = pacer.wait_until(due_ns).unwrap_or_else(unix_now_ns);
            let (mut meta, data, n) = match &step {
                Step::Spikes(c) => {
                    urn = SpikeChunk::TYPE_URN;
                    let (m, d) = c.to_arrow();
                    (m, d, c.n_planes as u64)
                }
                Step::Events(b) => {
                    urn = EventBatch::TYPE_URN;
                    let (m, d) = b.to_arrow();
                    (m, d, b.len() as u64)
                }
            };
            meta.set_int(ORIGIN_UNIX_NS, origin);
            let seq = meta.uint("message", neuspike_schemas::meta::SEQ)?;
            put(urn, &meta, &data)?;
            count = count.max(seq + 1);
            messages += 1;
            items += n;
        }
        Ok(())
    })();
    // The end, whatever happened: the receiver can tell a whole stream from a cut one.
    let (mut meta, data) = if spikes {
        end_of_stream::<SpikeChunk>(count)
    } else {
        end_of_stream::<EventBatch>(count)
    };
    if played.is_err() {
        meta.insert(
            neuspike_schemas::meta::CUT.into(),
            neuspike_schemas::Parameter::Bool(true),
        );
    }
    let urn = if spikes {
        SpikeChunk::TYPE_URN
    } else {
        EventBatch::TYPE_URN
    };
    let ended = put(urn, &meta, &data);
    played?;
    ended?;
    // Closing the session drops what is still queued on the link, and a receiver working
    // through its backlog may hold seconds of it: wait for the subscribers to leave, which they
    // do once they have taken the end-of-stream marker.
    if !neuspike_net::session::wait_unmatched(&[&publisher], Duration::from_secs(opts.wait_s)) {
        tracing::warn!(
            key = %key,
            wait_s = opts.wait_s,
            "a subscriber still listens after the end of the stream; closing"
        );
    }
    Ok(Published {
        key,
        messages,
        items,
        spikes,
        elapsed: start.elapsed(),
    })
}

/// The recording's next message and when the camera finished it (ns from the stream's start).
type NextStep = dyn FnMut() -> eyre::Result<Option<(Step, i64)>>;

enum Step {
    Spikes(SpikeChunk),
    Events(EventBatch),
}
