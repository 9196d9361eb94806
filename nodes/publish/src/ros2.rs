//! What a ROS 2 system running rmw_zenoh (Jazzy and later) needs to see a topic: the data key,
//! the liveliness tokens of the node and its publisher, the attachment every sample carries, and
//! `sensor_msgs/msg/Image` in CDR. The conventions are rmw_zenoh's (`docs/design.md` and its
//! `liveliness_utils.cpp`, `attachment_helpers.cpp`): see `docs/robots.md`.

use neuspike_schemas::Frame;
use neuspike_sink::png_out::{BitDepth, grey_levels};

/// The DDS type name of `sensor_msgs/msg/Image`.
pub const IMAGE_TYPE: &str = "sensor_msgs::msg::dds_::Image_";
/// Its type hash (RIHS01: sha256 of its type description), as Jazzy and later announce it.
pub const IMAGE_HASH: &str =
    "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47";
/// The DDS type name of `event_camera_msgs/msg/EventPacket`.
pub const EVENT_PACKET_TYPE: &str = "event_camera_msgs::msg::dds_::EventPacket_";
/// Its type hash, from its definition (`msg_ros2/EventPacket.msg` of event_camera_msgs: header,
/// height, width, seq, time_base, encoding, `bool` is_bigendian, events), as rosbags 0.11
/// computes it for Jazzy and later.
pub const EVENT_PACKET_HASH: &str =
    "RIHS01_d6fa176260b1f37e5a40845305315e150a0f18191241eb64f407442aa29844aa";

/// QoS as rmw_zenoh writes it in a liveliness token: reliable, volatile, keep last 10.
pub const QOS_RELIABLE_DEPTH_10: &str = "::,10:,:,:,,";

/// How a frame's pixels go into an Image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Encoding {
    /// 8-bit grey, `round(clamp(v) * 255)` as the sink's PNGs.
    Mono8,
    /// 16-bit grey (little-endian), `round(clamp(v) * 65535)`.
    Mono16,
    /// The luminance itself, 32-bit float (little-endian), not clamped.
    #[value(name = "32FC1")]
    Float32,
}

impl Encoding {
    /// The `encoding` string of the Image.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Mono8 => "mono8",
            Encoding::Mono16 => "mono16",
            Encoding::Float32 => "32FC1",
        }
    }

    fn bytes_per_pixel(self) -> usize {
        match self {
            Encoding::Mono8 => 1,
            Encoding::Mono16 => 2,
            Encoding::Float32 => 4,
        }
    }
}

/// A CDR (little-endian, XCDR1) writer: each primitive aligned to its own size, counted from
/// after the 4-byte encapsulation header.
struct Cdr(Vec<u8>);

impl Cdr {
    fn new(capacity: usize) -> Self {
        let mut v = Vec::with_capacity(capacity + 64);
        v.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        Cdr(v)
    }

    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }

    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn i32(&mut self, v: i32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn u64(&mut self, v: u64) {
        self.align(8);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }

    /// A string: its length counting the NUL, its bytes, the NUL.
    fn string(&mut self, s: &str) {
        self.u32(u32::try_from(s.len() + 1).unwrap_or(u32::MAX));
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }

    /// A byte sequence: its count, then the bytes.
    fn bytes(&mut self, b: &[u8]) {
        self.u32(u32::try_from(b.len()).unwrap_or(u32::MAX));
        self.0.extend_from_slice(b);
    }
}

/// `(sec, nanosec)` of a time in ns since the epoch (floored: a time before the epoch has a
/// negative `sec` and `nanosec` in `0..1e9`, as `builtin_interfaces/Time` wants).
pub fn stamp(t_ns: i64) -> (i32, u32) {
    let sec = t_ns.div_euclid(1_000_000_000);
    let nanosec = t_ns.rem_euclid(1_000_000_000) as u32;
    (
        i32::try_from(sec).unwrap_or(if sec < 0 { i32::MIN } else { i32::MAX }),
        nanosec,
    )
}

/// An Image in CDR from raw rows: `height` rows of `step` bytes.
pub fn image_cdr(
    stamp_ns: i64,
    frame_id: &str,
    height: u32,
    width: u32,
    encoding: &str,
    step: u32,
    data: &[u8],
) -> Vec<u8> {
    let mut c = Cdr::new(data.len() + frame_id.len() + encoding.len());
    let (sec, nanosec) = stamp(stamp_ns);
    c.i32(sec);
    c.u32(nanosec);
    c.string(frame_id);
    c.u32(height);
    c.u32(width);
    c.string(encoding);
    c.u8(0); // is_bigendian: little-endian data
    c.u32(step);
    c.bytes(data);
    c.0
}

/// An `event_camera_msgs/msg/EventPacket` in CDR: `events` in `encoding` (`evt3`: EVT 3.0 words,
/// `time_base` unused), numbered `seq` so that a subscriber sees a lost packet.
#[allow(clippy::too_many_arguments)]
pub fn event_packet_cdr(
    stamp_ns: i64,
    frame_id: &str,
    height: u32,
    width: u32,
    seq: u64,
    time_base: u64,
    encoding: &str,
    events: &[u8],
) -> Vec<u8> {
    let mut c = Cdr::new(events.len() + frame_id.len() + encoding.len());
    let (sec, nanosec) = stamp(stamp_ns);
    c.i32(sec);
    c.u32(nanosec);
    c.string(frame_id);
    c.u32(height);
    c.u32(width);
    c.u64(seq);
    c.u64(time_base);
    c.string(encoding);
    c.u8(0); // is_bigendian: false
    c.bytes(events);
    c.0
}

/// `frame` as an Image in CDR, stamped `stamp_ns`, in `encoding`.
pub fn frame_image(frame: &Frame, stamp_ns: i64, frame_id: &str, encoding: Encoding) -> Vec<u8> {
    let (h, w) = frame.data.dim();
    let data: Vec<u8> = match encoding {
        Encoding::Mono8 => grey_levels(frame.data.view(), BitDepth::Eight)
            .into_iter()
            .map(|v| v as u8)
            .collect(),
        Encoding::Mono16 => grey_levels(frame.data.view(), BitDepth::Sixteen)
            .into_iter()
            .flat_map(u16::to_le_bytes)
            .collect(),
        Encoding::Float32 => frame.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
    };
    let step = w * encoding.bytes_per_pixel();
    image_cdr(
        stamp_ns,
        frame_id,
        u32::try_from(h).unwrap_or(u32::MAX),
        u32::try_from(w).unwrap_or(u32::MAX),
        encoding.name(),
        u32::try_from(step).unwrap_or(u32::MAX),
        &data,
    )
}

/// The attachment rmw_zenoh requires on every sample (a subscriber drops a sample without it):
/// the sequence number (from 1), the source time in ns since the epoch, then the publisher's GID
/// as a 16-byte sequence (its length, 16, as one byte first).
pub fn attachment(seq: i64, source_ns: i64, gid: &[u8; 16]) -> [u8; 33] {
    let mut a = [0u8; 33];
    a[..8].copy_from_slice(&seq.to_le_bytes());
    a[8..16].copy_from_slice(&source_ns.to_le_bytes());
    a[16] = 16;
    a[17..].copy_from_slice(gid);
    a
}

/// A name as a liveliness token holds it: every `/` becomes `%`; empty is `%`.
pub fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".to_string()
    } else {
        name.replace('/', "%")
    }
}

/// A topic name without its leading and trailing `/` (`/neuspike/frame/` -> `neuspike/frame`).
pub fn strip_topic(topic: &str) -> &str {
    topic.trim_matches('/')
}

/// Where one ROS 2 node of this process lives: its domain, session id and names.
#[derive(Clone, Debug)]
pub struct RosNode {
    /// ROS domain id.
    pub domain: u32,
    /// The zenoh session id, hex, as the session reports it.
    pub zid: String,
    /// The node's id within the session (a counter).
    pub node_id: u32,
    /// Namespace (`/` for none).
    pub namespace: String,
    /// Node name.
    pub name: String,
}

impl RosNode {
    /// The node's own liveliness token (`ros2 node list` reads these).
    pub fn node_token(&self) -> String {
        format!(
            "@ros2_lv/{}/{}/{}/{}/NN/%/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            self.node_id,
            mangle(self.namespace.trim_end_matches('/')),
            mangle(&self.name)
        )
    }

    /// The data key of `topic` carrying type `dds_type` with hash `hash`.
    pub fn data_key(&self, topic: &str, dds_type: &str, hash: &str) -> String {
        format!(
            "{}/{}/{}/{}",
            self.domain,
            strip_topic(topic),
            dds_type,
            hash
        )
    }

    /// The liveliness token of publisher `entity_id` on `topic` (`ros2 topic list` reads these).
    pub fn publisher_token(
        &self,
        entity_id: u32,
        topic: &str,
        dds_type: &str,
        hash: &str,
    ) -> String {
        format!(
            "@ros2_lv/{}/{}/{}/{}/MP/%/{}/{}/{}/{}/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            entity_id,
            mangle(self.namespace.trim_end_matches('/')),
            mangle(&self.name),
            mangle(&format!("/{}", strip_topic(topic))),
            dds_type,
            hash,
            QOS_RELIABLE_DEPTH_10
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::FrameKind;

    #[test]
    fn an_image_in_cdr_is_byte_for_byte_what_rosbags_writes() {
        // rosbags 0.11.9: a 2x2 mono8 image, stamp {1, 2}, frame_id "cam", data 0a 14 1e 28.
        let expected: Vec<u8> = [
            &[0x00, 0x01, 0x00, 0x00][..],
            &[1, 0, 0, 0],
            &[2, 0, 0, 0],
            &[4, 0, 0, 0, b'c', b'a', b'm', 0],
            &[2, 0, 0, 0],
            &[2, 0, 0, 0],
            &[6, 0, 0, 0, b'm', b'o', b'n', b'o', b'8', 0],
            &[0],
            &[0],
            &[2, 0, 0, 0],
            &[4, 0, 0, 0],
            &[0x0a, 0x14, 0x1e, 0x28],
        ]
        .concat();
        let got = image_cdr(
            1_000_000_002,
            "cam",
            2,
            2,
            "mono8",
            2,
            &[0x0a, 0x14, 0x1e, 0x28],
        );
        assert_eq!(got, expected);
        assert_eq!(got.len(), 52);
    }

    #[test]
    fn an_event_packet_in_cdr_is_byte_for_byte_what_rosbags_writes() {
        // rosbags 0.11: stamp {1, 2}, frame_id "dvs", 260x346, seq 7, time_base 0, "evt3",
        // events 11 22 33 44.
        let hex = concat!(
            "00010000",
            "01000000",
            "02000000",
            "04000000",
            "64767300",
            "04010000",
            "5a010000",
            "0700000000000000",
            "0000000000000000",
            "05000000",
            "6576743300",
            "00",
            "0000",
            "04000000",
            "11223344"
        );
        let expected: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).expect("hex"))
            .collect();
        let got = event_packet_cdr(
            1_000_000_002,
            "dvs",
            260,
            346,
            7,
            0,
            "evt3",
            &[0x11, 0x22, 0x33, 0x44],
        );
        assert_eq!(got, expected);
        assert_eq!(got.len(), 64);
    }

    #[test]
    fn frames_go_into_images_in_each_encoding() {
        let frame = Frame {
            kind: FrameKind::Reconstruction,
            method: "tfp".into(),
            t_ref_ns: 0,
            compute_ns: 0,
            seq: 0,
            data: ndarray::array![[0.0f32, 1.0, 0.5], [2.0, -1.0, f32::NAN]],
        };
        let tail = |b: &[u8], n: usize| b[b.len() - n..].to_vec();
        let m8 = frame_image(&frame, 0, "f", Encoding::Mono8);
        assert_eq!(tail(&m8, 6), [0, 255, 128, 255, 0, 0]);
        let m16 = frame_image(&frame, 0, "f", Encoding::Mono16);
        assert_eq!(tail(&m16, 6), [0xff, 0xff, 0, 0, 0, 0]);
        let f32s = frame_image(&frame, 0, "f", Encoding::Float32);
        assert_eq!(tail(&f32s, 4), f32::NAN.to_le_bytes());
        // step, then the data length, just before the data.
        let n = f32s.len();
        assert_eq!(f32s[n - 24 - 8..n - 24 - 4], 12u32.to_le_bytes());
        assert_eq!(f32s[n - 24 - 4..n - 24], 24u32.to_le_bytes());
    }

    #[test]
    fn stamps_attachments_and_names_follow_rmw_zenoh() {
        assert_eq!(stamp(1_500_000_000), (1, 500_000_000));
        assert_eq!(stamp(-1), (-1, 999_999_999));
        let a = attachment(1, 0x0102, &[7; 16]);
        assert_eq!(a[..8], 1i64.to_le_bytes());
        assert_eq!(a[8..16], 0x0102i64.to_le_bytes());
        assert_eq!(a[16], 16);
        assert_eq!(a[17..], [7; 16]);
        let node = RosNode {
            domain: 0,
            zid: "ab12".into(),
            node_id: 0,
            namespace: "/".into(),
            name: "neuspike".into(),
        };
        assert_eq!(
            node.data_key("/neuspike/frame", IMAGE_TYPE, IMAGE_HASH),
            format!("0/neuspike/frame/{IMAGE_TYPE}/{IMAGE_HASH}")
        );
        assert_eq!(node.node_token(), "@ros2_lv/0/ab12/0/0/NN/%/%/neuspike");
        assert_eq!(
            node.publisher_token(1, "/neuspike/frame", IMAGE_TYPE, IMAGE_HASH),
            format!(
                "@ros2_lv/0/ab12/0/1/MP/%/%/neuspike/%neuspike%frame/{IMAGE_TYPE}/{IMAGE_HASH}/::,10:,:,:,,"
            )
        );
        assert_eq!(mangle("/a/b"), "%a%b");
    }
}
