//! The publish stage: what a graph makes, on zenoh for anyone who listens, and on ROS 2.
//!
//! - Every input goes out as neuspike's own message (Arrow IPC, [`neuspike_schemas::ipc`]) on the
//!   key `neuspike/<graph>/<input>`, header included, so that a subscriber decodes it with
//!   `neuspike-schemas` (or pyarrow) and tells a lost message by its sequence number.
//! - Inputs named with `--ros2 INPUT=TOPIC[:ENCODING]` also go out as `sensor_msgs/msg/Image` on
//!   rmw_zenoh's keys, with the liveliness tokens that make `ros2 topic list` show them and the
//!   attachment every rmw_zenoh sample carries ([`ros2`]).
//! - The zenoh session: peer mode, listening on loopback only, dialling a router on
//!   `tcp/127.0.0.1:7447` (rmw_zenoh's `rmw_zenohd`) when one runs, multicast scouting off.
//!   Anything else (other endpoints, a router elsewhere, TLS) comes from a zenoh JSON5 file
//!   (`--zenoh-config`).

pub mod bag;
pub mod image;

use std::collections::BTreeMap;

use eyre::{WrapErr, bail, eyre};
use neuspike_formats::Resolution;
use neuspike_schemas::arrow::array::ArrayRef;
use neuspike_schemas::{EventBatch, Frame, Message, Meta, ipc, is_end_of_stream};
use zenoh::Wait;

use neuspike_net::ZenohArgs;
use neuspike_net::ros2::{
    self, EVENT_PACKET_HASH, EVENT_PACKET_TYPE, IMAGE_HASH, IMAGE_TYPE, RosNode,
};

use crate::image::Encoding;

/// The node's settings (the graph's `args:`).
#[derive(Clone, Debug, clap::Args)]
pub struct PublishConfig {
    /// The graph's name: keys are `neuspike/<graph>/<input>`.
    #[arg(long, default_value = "neuspike")]
    pub graph: String,
    /// Publish INPUT (a Frame input) as a ROS 2 `sensor_msgs/msg/Image` on TOPIC, in ENCODING
    /// `mono8` (default), `mono16` or `32FC1`, e.g. `--ros2 tfp=/neuspike/tfp:mono16`.
    /// Repeatable.
    #[arg(long = "ros2", value_name = "INPUT=TOPIC[:ENCODING]", value_parser = parse_ros2)]
    pub ros2: Vec<RosTopic>,
    /// Publish INPUT (an EventBatch input) as a ROS 2 `event_camera_msgs/msg/EventPacket` with
    /// encoding `evt3` on TOPIC, as ROS 2 event-camera drivers do, e.g.
    /// `--ros2-events events=/event_camera/events`. Repeatable.
    #[arg(long = "ros2-events", value_name = "INPUT=TOPIC", value_parser = parse_ros2_events)]
    pub ros2_events: Vec<RosTopic>,
    /// ROS domain id.
    #[arg(long, default_value_t = 0)]
    pub ros_domain: u32,
    /// The ROS 2 node name the topics belong to.
    #[arg(long, default_value = "neuspike")]
    pub ros_node: String,
    /// The ROS 2 namespace.
    #[arg(long, default_value = "/")]
    pub ros_namespace: String,
    /// `header.frame_id` of the images.
    #[arg(long, default_value = "neuspike")]
    pub frame_id: String,
    /// Send with zenoh's congestion control `block` (default: a slow subscriber holds the graph
    /// back, nothing is lost) or `drop` (a live view that must never slow the graph).
    #[arg(long, value_enum, default_value_t = Congestion::Block)]
    pub congestion: Congestion,
    /// Also record the run into this MCAP file, as a ROS 2 bag (`ros2 bag play` reads it):
    /// every ROS 2 topic the node publishes, and neuspike's own messages under their keys. A
    /// relative path is relative to the graph's folder. Written as `<FILE>.partial` and renamed
    /// to FILE when the run ends: a bag under its own name is whole.
    #[arg(long)]
    pub mcap: Option<std::path::PathBuf>,
    /// After the graph's end, wait up to this many seconds for the subscribers to leave (they
    /// do once they have taken the end-of-stream markers) before closing the session, which
    /// drops what is still queued on its links. A subscriber that keeps listening holds the
    /// node this long; 0 closes at once.
    #[arg(long, default_value_t = 5.0)]
    pub linger_s: f64,
    /// The zenoh session.
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// What a publisher does when the link is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Congestion {
    /// Wait: lossless, and a slow subscriber slows the graph (its credits hold it back).
    Block,
    /// Drop the sample: never slows the graph; a subscriber sees the gap in `seq`.
    Drop,
}

impl Congestion {
    fn zenoh(self) -> zenoh::qos::CongestionControl {
        match self {
            Congestion::Block => zenoh::qos::CongestionControl::Block,
            Congestion::Drop => zenoh::qos::CongestionControl::Drop,
        }
    }
}

/// One `--ros2` entry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RosTopic {
    /// The input it takes.
    pub input: String,
    /// The topic, e.g. `/neuspike/tfp`.
    pub topic: String,
    /// How pixels are written.
    pub encoding: Encoding,
}

fn parse_ros2(s: &str) -> Result<RosTopic, String> {
    let (input, rest) = s
        .split_once('=')
        .ok_or_else(|| format!("`{s}`: expected INPUT=TOPIC[:ENCODING]"))?;
    let (topic, encoding) = match rest.rsplit_once(':') {
        Some((t, e)) => {
            let enc = <Encoding as clap::ValueEnum>::from_str(e, true)
                .map_err(|_| format!("`{s}`: encoding `{e}` is not mono8, mono16 or 32FC1"))?;
            (t, enc)
        }
        None => (rest, Encoding::Mono8),
    };
    let topic = ros2::strip_topic(topic);
    if input.is_empty() || topic.is_empty() {
        return Err(format!("`{s}`: the input and the topic must not be empty"));
    }
    if !topic
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
    {
        return Err(format!(
            "`{s}`: a ROS 2 topic holds letters, digits, `_` and `/` only"
        ));
    }
    Ok(RosTopic {
        input: input.to_string(),
        topic: format!("/{topic}"),
        encoding,
    })
}

fn parse_ros2_events(s: &str) -> Result<RosTopic, String> {
    if s.rsplit_once('=').is_some_and(|(_, t)| t.contains(':')) {
        return Err(format!(
            "`{s}`: event packets are EVT 3.0 (`evt3`); name no encoding"
        ));
    }
    parse_ros2(s)
}

impl PublishConfig {
    /// Checks the settings against the node's inputs: every `--ros2` input must be one.
    ///
    /// # Errors
    /// A `--ros2` entry names an input the node does not have, or two name one topic.
    pub fn check(&self, inputs: &[String]) -> eyre::Result<()> {
        let mut topics = BTreeMap::new();
        for r in self.ros2.iter().chain(&self.ros2_events) {
            if !inputs.contains(&r.input) {
                bail!(
                    "--ros2 {}={}: the node has no input `{}` (it has {})",
                    r.input,
                    r.topic,
                    r.input,
                    inputs.join(", ")
                );
            }
            if let Some(other) = topics.insert(r.topic.clone(), r.input.clone()) {
                bail!(
                    "--ros2: inputs `{other}` and `{}` both publish {}",
                    r.input,
                    r.topic
                );
            }
        }
        if self.graph.is_empty() || self.graph.contains(['*', '$', '#', '?']) {
            bail!(
                "--graph `{}`: a key expression chunk without * $ # ?",
                self.graph
            );
        }
        Ok(())
    }
}

/// What a ROS 2 topic carries.
#[derive(Clone, Copy, Debug)]
enum RosKind {
    /// `sensor_msgs/msg/Image` of frames.
    Image(Encoding),
    /// `event_camera_msgs/msg/EventPacket` (`evt3`) of event batches.
    Events,
}

/// A ROS 2 publisher.
struct RosImages {
    key: zenoh::pubsub::Publisher<'static>,
    topic: String,
    kind: RosKind,
    gid: [u8; 16],
    sent: i64,
    _token: zenoh::liveliness::LivelinessToken,
}

/// What the node publishes, on one zenoh session.
pub struct Publisher {
    graph: String,
    frame_id: String,
    session: zenoh::Session,
    arrow: BTreeMap<String, zenoh::pubsub::Publisher<'static>>,
    ros: BTreeMap<String, RosImages>,
    _node_token: Option<zenoh::liveliness::LivelinessToken>,
    published: u64,
    bag: Option<bag::Bag>,
    linger: std::time::Duration,
}

impl Publisher {
    /// Opens the session and declares a publisher for each input (and its ROS 2 topic).
    ///
    /// # Errors
    /// The session cannot open (an endpoint that cannot be bound), or a declaration fails.
    pub fn open(cfg: &PublishConfig, inputs: &[String]) -> eyre::Result<Self> {
        cfg.check(inputs)?;
        let session = cfg.zenoh.open()?;
        let mut arrow = BTreeMap::new();
        for input in inputs {
            let key = format!("neuspike/{}/{input}", cfg.graph);
            let p = session
                .declare_publisher(key.clone())
                .congestion_control(cfg.congestion.zenoh())
                .reliability(zenoh::qos::Reliability::Reliable)
                .wait()
                .map_err(|e| eyre!("cannot publish on {key}: {e}"))?;
            arrow.insert(input.clone(), p);
        }
        let mut ros = BTreeMap::new();
        let mut node_token = None;
        if !cfg.ros2.is_empty() || !cfg.ros2_events.is_empty() {
            let node = RosNode {
                domain: cfg.ros_domain,
                zid: session.zid().to_string(),
                node_id: 0,
                namespace: cfg.ros_namespace.clone(),
                name: cfg.ros_node.clone(),
            };
            node_token = Some(
                session
                    .liveliness()
                    .declare_token(node.node_token())
                    .wait()
                    .map_err(|e| eyre!("cannot declare the ROS 2 node: {e}"))?,
            );
            let topics = cfg
                .ros2
                .iter()
                .map(|r| (r, RosKind::Image(r.encoding), IMAGE_TYPE, IMAGE_HASH))
                .chain(
                    cfg.ros2_events
                        .iter()
                        .map(|r| (r, RosKind::Events, EVENT_PACKET_TYPE, EVENT_PACKET_HASH)),
                );
            for (i, (r, kind, dds_type, hash)) in topics.enumerate() {
                let entity = u32::try_from(i + 1).unwrap_or(u32::MAX);
                let key = node.data_key(&r.topic, dds_type, hash);
                let p = session
                    .declare_publisher(key.clone())
                    .congestion_control(cfg.congestion.zenoh())
                    .reliability(zenoh::qos::Reliability::Reliable)
                    .wait()
                    .map_err(|e| eyre!("cannot publish on {key}: {e}"))?;
                let token = session
                    .liveliness()
                    .declare_token(node.publisher_token(entity, &r.topic, dds_type, hash))
                    .wait()
                    .map_err(|e| eyre!("cannot declare the ROS 2 publisher of {}: {e}", r.topic))?;
                let mut gid = [0u8; 16];
                let zid = session.zid().to_le_bytes();
                gid[..zid.len().min(12)].copy_from_slice(&zid[..zid.len().min(12)]);
                gid[12..].copy_from_slice(&entity.to_le_bytes());
                ros.insert(
                    r.input.clone(),
                    RosImages {
                        key: p,
                        topic: r.topic.clone(),
                        kind,
                        gid,
                        sent: 0,
                        _token: token,
                    },
                );
            }
        }
        Ok(Publisher {
            graph: cfg.graph.clone(),
            frame_id: cfg.frame_id.clone(),
            session,
            arrow,
            ros,
            _node_token: node_token,
            published: 0,
            bag: cfg.mcap.as_deref().map(bag::Bag::create).transpose()?,
            linger: std::time::Duration::try_from_secs_f64(cfg.linger_s)
                .map_err(|_| eyre!("--linger-s {}: not a number of seconds", cfg.linger_s))?,
        })
    }

    /// The session's id (hex), as ROS 2 tools show it.
    pub fn zid(&self) -> String {
        self.session.zid().to_string()
    }

    /// The endpoints the session listens on (`tcp/127.0.0.1:41234`).
    pub fn locators(&self) -> Vec<String> {
        neuspike_net::session::locators(&self.session)
    }

    /// Messages published so far (each key counts).
    pub fn published(&self) -> u64 {
        self.published
    }

    /// Publishes one message of `input` (of type `type_urn`): as Arrow IPC on its key, and as an
    /// Image when it has a ROS 2 topic and is a frame (an end-of-stream marker goes on the
    /// Arrow key only). `now_ns` stamps the attachment.
    ///
    /// # Errors
    /// The message cannot be encoded, or zenoh refused it.
    pub fn publish(
        &mut self,
        input: &str,
        type_urn: &str,
        meta: &Meta,
        data: &ArrayRef,
        now_ns: i64,
    ) -> eyre::Result<()> {
        if let Some(p) = self.arrow.get(input) {
            let bytes = ipc::encode(type_urn, meta, data)
                .wrap_err_with(|| format!("input `{input}`: cannot encode"))?;
            if let Some(bag) = &mut self.bag {
                bag.neuspike(&format!("neuspike/{}/{input}", self.graph), &bytes, now_ns)?;
            }
            // The source number wraps at 2^32: a follower checks the identity, not the number.
            neuspike_net::put_message(p, bytes, self.published as u32)
                .map_err(|e| eyre!("neuspike/{}/{input}: {e}", self.graph))?;
            self.published += 1;
        }
        if is_end_of_stream(meta).is_some() {
            return Ok(());
        }
        if let Some(r) = self.ros.get_mut(input) {
            let cdr = match r.kind {
                RosKind::Image(encoding) => {
                    let frame = Frame::from_arrow(meta, data).wrap_err_with(|| {
                        format!("input `{input}`: a ROS 2 image needs a Frame")
                    })?;
                    image::frame_image(&frame, frame.t_ref_ns, &self.frame_id, encoding)
                }
                RosKind::Events => {
                    let batch = EventBatch::from_arrow(meta, data).wrap_err_with(|| {
                        format!("input `{input}`: a ROS 2 event packet needs an EventBatch")
                    })?;
                    let size = |v: usize| u16::try_from(v).unwrap_or(u16::MAX);
                    let resolution = Resolution {
                        width: size(batch.width),
                        height: size(batch.height),
                    };
                    let words = neuspike_formats::evt3::packet_words(&batch, resolution)
                        .wrap_err_with(|| format!("input `{input}`: cannot encode EVT 3.0"))?;
                    ros2::event_packet_cdr(
                        batch.t_start_ns,
                        &self.frame_id,
                        u32::from(resolution.height),
                        u32::from(resolution.width),
                        batch.seq,
                        0,
                        "evt3",
                        &words,
                    )
                }
            };
            r.sent += 1;
            if let Some(bag) = &mut self.bag {
                let (type_name, definition, stamp_ns) = match r.kind {
                    RosKind::Image(_) => (
                        "sensor_msgs/msg/Image",
                        bag::image_definition(),
                        stamp_of(meta, neuspike_schemas::meta::T_REF_NS),
                    ),
                    RosKind::Events => (
                        "event_camera_msgs/msg/EventPacket",
                        bag::event_packet_definition(),
                        stamp_of(meta, neuspike_schemas::meta::T_START_NS),
                    ),
                };
                bag.ros2(
                    &r.topic,
                    type_name,
                    &definition,
                    &cdr,
                    now_ns,
                    stamp_ns.unwrap_or(now_ns),
                )?;
            }
            let attachment = ros2::attachment(r.sent, now_ns, &r.gid);
            r.key
                .put(cdr)
                .attachment(attachment.to_vec())
                .wait()
                .map_err(|e| eyre!("input `{input}`: ROS 2 publish: {e}"))?;
            self.published += 1;
        }
        Ok(())
    }
}

impl Publisher {
    /// Finishes the bag, if the run is recorded (its summary and index), then waits up to the
    /// linger time for the subscribers to leave.
    ///
    /// # Errors
    /// The bag could not be written.
    pub fn finish(&mut self) -> eyre::Result<()> {
        let written = match self.bag.take() {
            Some(bag) => {
                let n = bag.messages();
                bag.finish().map(|path| {
                    tracing::info!(path = %path.display(), messages = n, "bag written");
                })
            }
            None => Ok(()),
        };
        let publishers: Vec<&zenoh::pubsub::Publisher<'static>> = self
            .arrow
            .values()
            .chain(self.ros.values().map(|r| &r.key))
            .collect();
        if !neuspike_net::session::wait_unmatched(&publishers, self.linger) {
            tracing::info!(
                linger_s = self.linger.as_secs_f64(),
                "subscribers still listen; closing"
            );
        }
        Ok(written?)
    }
}

fn stamp_of(meta: &Meta, key: &'static str) -> Option<i64> {
    match meta.get(key) {
        Some(neuspike_schemas::Parameter::Integer(t)) => Some(*t),
        _ => None,
    }
}

/// The message type of `Frame` inputs, for a node that cannot tell.
pub const FRAME_URN: &str = Frame::TYPE_URN;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros2_entries_parse_with_their_encoding_and_bad_ones_say_why() {
        let r = parse_ros2("tfp=/neuspike/tfp:mono16").expect("entry");
        assert_eq!(
            (r.input.as_str(), r.topic.as_str(), r.encoding),
            ("tfp", "/neuspike/tfp", Encoding::Mono16)
        );
        assert_eq!(parse_ros2("a=cam/x").expect("entry").topic, "/cam/x");
        assert_eq!(
            parse_ros2("a=/x:32FC1").expect("entry").encoding,
            Encoding::Float32
        );
        assert!(parse_ros2_events("ev=/event_camera/events:mono").is_err());
        for bad in ["tfp", "=x", "a=", "a=/x:rgb8", "a=/x y"] {
            assert!(parse_ros2(bad).is_err(), "{bad}");
        }
        let cfg = PublishConfig {
            graph: "g".into(),
            ros2: vec![parse_ros2("tfp=/a").expect("a")],
            ros2_events: vec![parse_ros2_events("tfi=/a").expect("b")],
            ros_domain: 0,
            ros_node: "n".into(),
            ros_namespace: "/".into(),
            frame_id: "f".into(),
            congestion: Congestion::Block,
            linger_s: 0.0,
            mcap: None,
            zenoh: ZenohArgs::default(),
        };
        let inputs = ["tfp".to_string(), "tfi".to_string()];
        let e = cfg.check(&inputs).expect_err("one topic twice").to_string();
        assert!(e.contains("/a"), "{e}");
        let e = cfg
            .check(&inputs[..1])
            .expect_err("no input tfi")
            .to_string();
        assert!(e.contains("no input `tfi`"), "{e}");
    }
}
