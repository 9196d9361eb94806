//! dora node: the DVS event camera, simulated or played from a recording. Output `events`
//! (EventBatch), one batch per `--batch-ns` interval, empty batches included, so a receiver always
//! knows how far time went (a gap in a recording longer than two intervals is one empty batch
//! across it). The stage itself (the settings, the scene or the recording, the
//! batches) is `neuspike_event_camera::playback`.
//!
//! A recording that turns out bad part-way has every batch before the fault sent, then the
//! end-of-stream marker, and the node fails naming the file and the byte offset or line. A
//! relative `--file` is resolved against the node's working directory: under `neuspike run`
//! (dora), the graph's folder. `--pace realtime` sends each batch when the camera would have
//! finished it (wall clock from the node's start, camera clock from the stream's start); `--pace
//! fast` (default) sends as fast as the receivers take them.
//!
//! Or the camera is elsewhere: `--from-zenoh KEY` takes EventBatch messages another machine
//! publishes (`neuspike publish-file`, a graph's publish node), lost ones counted by their
//! sequence numbers; `--from-ros2 TOPIC` takes `event_camera_msgs/msg/EventPacket` (`evt3` or
//! `mono`) from a ROS 2 event-camera driver over rmw_zenoh.

use dora_node_api::{DoraNode, EventStream};
use std::time::Duration;

use neuspike_event_camera::playback::{EventSource, EventSourceConfig, EventSourceStage};
use neuspike_event_camera::ros2::{RosEvents, RosTaken};
use neuspike_net::{Remote, ZenohArgs};
use neuspike_runtime::{Arrival, Link, Pace, Pacer, relay, relay_remote};
use neuspike_schemas::{EventBatch, Message};

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
    /// Take the events from this zenoh key instead of a scene or a file: EventBatch messages
    /// (Arrow IPC) as another machine publishes them, e.g. `neuspike/camera/events`.
    #[arg(long, value_name = "KEY", conflicts_with_all = ["file", "from_ros2"])]
    from_zenoh: Option<String>,
    /// Take the events from this ROS 2 topic instead: `event_camera_msgs/msg/EventPacket`
    /// (`evt3` or `mono`) over rmw_zenoh, e.g. `/event_camera/events`.
    #[arg(long, value_name = "TOPIC", conflicts_with = "file")]
    from_ros2: Option<String>,
    /// The ROS domain of `--from-ros2`.
    #[arg(long, default_value_t = 0)]
    ros_domain: u32,
    /// Seconds without a message before a network source stops: an error before the first
    /// message (and, for `--from-zenoh`, before the end-of-stream marker); for `--from-ros2`,
    /// whose topics never end, the end of the stream once packets came.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    silence_s: u64,
    /// The zenoh session of `--from-zenoh` and `--from-ros2`.
    #[command(flatten)]
    zenoh: ZenohArgs,
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
    if args.from_zenoh.is_some() || args.from_ros2.is_some() {
        if args.pace != Pace::Fast {
            eyre::bail!(
                "event-source: --pace {:?} with a network camera: the camera sets the pace",
                args.pace
            );
        }
        let (node, events) = neuspike_runtime::init_node()?;
        return run_network(node, events, &args);
    }
    let source = open_source(&args)?;
    let (node, events) = neuspike_runtime::init_node()?;
    neuspike_runtime::run_on_rayon("event-source", || run(node, events, source, &args))
}

/// Relays a network camera's events: neuspike's own batches, or a ROS 2 driver's packets.
fn run_network(node: DoraNode, events: EventStream, args: &Args) -> eyre::Result<()> {
    let silence = Duration::from_secs(args.silence_s);
    let session = args.zenoh.open()?;
    let mut out = Link::new(node, events)?;
    out.declare::<EventBatch>("events");
    if let Some(key) = &args.from_zenoh {
        let mut remote = Remote::subscribe(&session, key, EventBatch::TYPE_URN, silence)?
            .rejoining_after(args.zenoh.rejoin_after()?);
        tracing::info!(key, "waiting for event batches");
        return relay_remote::<EventBatch>(&mut out, "events", &mut remote);
    }
    let topic = args.from_ros2.as_deref().unwrap_or_default();
    let mut ros =
        RosEvents::subscribe(&session, topic, args.ros_domain, "neuspike_events", silence)?
            .rejoining_after(args.zenoh.rejoin_after()?);
    tracing::info!(topic, "waiting for event packets");
    let relayed = relay(&mut out, "events", |wait| {
        Ok(match ros.next(wait)? {
            RosTaken::Batch(batch, origin) => Arrival::Message(batch, origin),
            // A topic has no end: what came is the whole stream.
            RosTaken::End => Arrival::End {
                count: 0,
                cut: false,
            },
            RosTaken::Idle => Arrival::Idle,
        })
    });
    tracing::info!(
        topic,
        packets = ros.decoder().packets(),
        lost = ros.decoder().lost_packets(),
        "the ROS 2 event stream ended"
    );
    relayed
}

/// Sends every batch, then the end-of-stream marker, whatever happened.
fn run(node: DoraNode, events: EventStream, source: EventSource, args: &Args) -> eyre::Result<()> {
    source.log_start();
    let mut stage = EventSourceStage::new(source, Pacer::start(args.pace));
    neuspike_runtime::run_stage(node, events, &mut stage)
}

#[cfg(test)]
mod node_tests;
