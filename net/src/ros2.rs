//! What a ROS 2 system running rmw_zenoh (Jazzy and later) needs to see a topic: the data key,
//! the liveliness tokens of the node and its publisher, the attachment every sample carries, and
//! `sensor_msgs/msg/Image` and `event_camera_msgs/msg/EventPacket` in CDR, written and read. The conventions are rmw_zenoh's (`docs/design.md` and its
//! `liveliness_utils.cpp`, `attachment_helpers.cpp`): see `docs/robots.md`.

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

/// An rmw_zenoh attachment read back: what [`attachment`] writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's sequence number, from 1.
    pub seq: i64,
    /// The source time, ns since the epoch.
    pub source_ns: i64,
    /// The publisher's GID.
    pub gid: [u8; 16],
}

/// Reads an rmw_zenoh attachment (33 bytes: sequence number, source time, GID length 16, GID).
///
/// # Errors
/// Another length, or a GID length byte other than 16.
pub fn parse_attachment(bytes: &[u8]) -> Result<Attachment, CdrError> {
    let Ok(a) = <&[u8; 33]>::try_from(bytes) else {
        return Err(CdrError::new(
            "attachment",
            0,
            format!("{} bytes, an rmw_zenoh attachment has 33", bytes.len()),
        ));
    };
    if a[16] != 16 {
        return Err(CdrError::new(
            "attachment",
            16,
            format!("GID length {}, expected 16", a[16]),
        ));
    }
    let word = |at: usize| {
        let mut w = [0u8; 8];
        w.copy_from_slice(&a[at..at + 8]);
        i64::from_le_bytes(w)
    };
    let mut gid = [0u8; 16];
    gid.copy_from_slice(&a[17..]);
    Ok(Attachment {
        seq: word(0),
        source_ns: word(8),
        gid,
    })
}

/// Bytes that are not the CDR of the message expected: the message, the byte offset and what was
/// wrong.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}: at byte {offset}: {what}")]
pub struct CdrError {
    /// The message type read.
    pub message: &'static str,
    /// Where in the bytes.
    pub offset: usize,
    /// What was wrong, with the value found.
    pub what: String,
}

impl CdrError {
    fn new(message: &'static str, offset: usize, what: String) -> Self {
        CdrError {
            message,
            offset,
            what,
        }
    }
}

/// A CDR reader (little-endian XCDR1, as [`Cdr`] writes): every length is checked against the
/// bytes left before anything is taken, so no claim in the bytes makes it allocate.
struct CdrReader<'a> {
    bytes: &'a [u8],
    at: usize,
    message: &'static str,
}

impl<'a> CdrReader<'a> {
    fn new(message: &'static str, bytes: &'a [u8]) -> Result<Self, CdrError> {
        match bytes.get(..4) {
            Some([0x00, 0x01, _, _]) => Ok(CdrReader {
                bytes,
                at: 4,
                message,
            }),
            Some(h) => Err(CdrError::new(
                message,
                0,
                format!(
                    "encapsulation {:02x} {:02x}, expected 00 01 (CDR, little-endian)",
                    h[0], h[1]
                ),
            )),
            None => Err(CdrError::new(
                message,
                0,
                format!("{} bytes, shorter than the CDR header", bytes.len()),
            )),
        }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CdrError> {
        let left = self.bytes.len() - self.at;
        if n > left {
            return Err(CdrError::new(
                self.message,
                self.at,
                format!("{what} needs {n} bytes, {left} left"),
            ));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    fn align(&mut self, n: usize, what: &str) -> Result<(), CdrError> {
        let pad = (n - (self.at - 4) % n) % n;
        self.take(pad, what).map(|_| ())
    }

    fn u8(&mut self, what: &str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, CdrError> {
        self.align(4, what)?;
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn i32(&mut self, what: &str) -> Result<i32, CdrError> {
        self.u32(what).map(|v| v as i32)
    }

    fn u64(&mut self, what: &str) -> Result<u64, CdrError> {
        self.align(8, what)?;
        let b = self.take(8, what)?;
        let mut w = [0u8; 8];
        w.copy_from_slice(b);
        Ok(u64::from_le_bytes(w))
    }

    fn string(&mut self, what: &str) -> Result<String, CdrError> {
        let at = self.at;
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        match b.split_last() {
            Some((0, text)) => std::str::from_utf8(text)
                .map(str::to_string)
                .map_err(|_| CdrError::new(self.message, at, format!("{what} is not UTF-8"))),
            _ => Err(CdrError::new(
                self.message,
                at,
                format!("{what} of {n} bytes does not end with NUL"),
            )),
        }
    }

    fn bytes(&mut self, what: &str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(what)? as usize;
        self.take(n, what)
    }

    /// A `std_msgs/Header`: the stamp in ns since the epoch, and the frame id.
    fn header(&mut self) -> Result<(i64, String), CdrError> {
        let sec = self.i32("header.stamp.sec")?;
        let nanosec = self.u32("header.stamp.nanosec")?;
        let frame_id = self.string("header.frame_id")?;
        Ok((
            i64::from(sec) * 1_000_000_000 + i64::from(nanosec.min(999_999_999)),
            frame_id,
        ))
    }

    /// The message ends here: at most the 3 bytes of padding a writer may align its end to.
    fn end(&self) -> Result<(), CdrError> {
        let left = self.bytes.len() - self.at;
        if left > 3 {
            return Err(CdrError::new(
                self.message,
                self.at,
                format!("{left} bytes after the message"),
            ));
        }
        Ok(())
    }
}

/// An `event_camera_msgs/msg/EventPacket` read from CDR.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EventPacket {
    /// `header.stamp`, ns since the epoch.
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub frame_id: String,
    /// Sensor height.
    pub height: u32,
    /// Sensor width.
    pub width: u32,
    /// The driver's packet counter (a gap is packets lost).
    pub seq: u64,
    /// The time base of encodings that use one (`mono`: ns).
    pub time_base: u64,
    /// `evt3`, `mono`, ...
    pub encoding: String,
    /// Whether `events` is big-endian.
    pub is_bigendian: bool,
    /// The encoded events.
    pub events: Vec<u8>,
}

/// Reads an `event_camera_msgs/msg/EventPacket` from its CDR bytes.
///
/// # Errors
/// The bytes end early, a length claims more than is left, a string is not NUL-terminated UTF-8,
/// or bytes follow the message (beyond alignment padding).
pub fn parse_event_packet(bytes: &[u8]) -> Result<EventPacket, CdrError> {
    let mut r = CdrReader::new("EventPacket", bytes)?;
    let (stamp_ns, frame_id) = r.header()?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let seq = r.u64("seq")?;
    let time_base = r.u64("time_base")?;
    let encoding = r.string("encoding")?;
    let is_bigendian = r.u8("is_bigendian")? != 0;
    let events = r.bytes("events")?.to_vec();
    r.end()?;
    Ok(EventPacket {
        stamp_ns,
        frame_id,
        height,
        width,
        seq,
        time_base,
        encoding,
        is_bigendian,
        events,
    })
}

/// A `sensor_msgs/msg/Image` read from CDR.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// `header.stamp`, ns since the epoch.
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub frame_id: String,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `mono8`, `mono16`, `32FC1`, ...
    pub encoding: String,
    /// Whether multi-byte pixels are big-endian.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// `height` rows of `step` bytes.
    pub data: Vec<u8>,
}

/// Reads a `sensor_msgs/msg/Image` from its CDR bytes and checks that `data` holds `height`
/// rows of `step` bytes.
///
/// # Errors
/// As [`parse_event_packet`], or `data` disagrees with `height x step`.
pub fn parse_image(bytes: &[u8]) -> Result<Image, CdrError> {
    let mut r = CdrReader::new("Image", bytes)?;
    let (stamp_ns, frame_id) = r.header()?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let encoding = r.string("encoding")?;
    let is_bigendian = r.u8("is_bigendian")? != 0;
    let step = r.u32("step")?;
    let at = r.at;
    let data = r.bytes("data")?.to_vec();
    if u64::from(height) * u64::from(step) != data.len() as u64 {
        return Err(CdrError::new(
            "Image",
            at,
            format!(
                "data of {} bytes, {height} rows of {step} bytes need {}",
                data.len(),
                u64::from(height) * u64::from(step)
            ),
        ));
    }
    r.end()?;
    Ok(Image {
        stamp_ns,
        frame_id,
        height,
        width,
        encoding,
        is_bigendian,
        step,
        data,
    })
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

    /// The liveliness token of subscription `entity_id` on `topic` (`ros2 topic info` counts
    /// these).
    pub fn subscriber_token(
        &self,
        entity_id: u32,
        topic: &str,
        dds_type: &str,
        hash: &str,
    ) -> String {
        self.entity_token("MS", entity_id, topic, dds_type, hash)
    }

    /// The liveliness token of publisher `entity_id` on `topic` (`ros2 topic list` reads these).
    pub fn publisher_token(
        &self,
        entity_id: u32,
        topic: &str,
        dds_type: &str,
        hash: &str,
    ) -> String {
        self.entity_token("MP", entity_id, topic, dds_type, hash)
    }

    fn entity_token(
        &self,
        kind: &str,
        entity_id: u32,
        topic: &str,
        dds_type: &str,
        hash: &str,
    ) -> String {
        format!(
            "@ros2_lv/{}/{}/{}/{}/{kind}/%/{}/{}/{}/{}/{}/{}",
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
    fn event_packets_read_back_and_damage_is_named() {
        let bytes = event_packet_cdr(
            1_000_000_002,
            "dvs",
            260,
            346,
            7,
            99,
            "evt3",
            &[0x11, 0x22, 0x33, 0x44],
        );
        let p = parse_event_packet(&bytes).expect("packet");
        assert_eq!(
            p,
            EventPacket {
                stamp_ns: 1_000_000_002,
                frame_id: "dvs".into(),
                height: 260,
                width: 346,
                seq: 7,
                time_base: 99,
                encoding: "evt3".into(),
                is_bigendian: false,
                events: vec![0x11, 0x22, 0x33, 0x44],
            }
        );
        // Every cut is an error, never a panic.
        for cut in 0..bytes.len() {
            assert!(parse_event_packet(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        // A sequence claiming 4 GiB is refused before anything is allocated for it.
        let mut huge = bytes.clone();
        let n = huge.len();
        huge[n - 8..n - 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = parse_event_packet(&huge).expect_err("huge").to_string();
        assert!(e.contains("events needs 4294967295 bytes, 4 left"), "{e}");
        let mut big_endian = bytes.clone();
        big_endian[1] = 0x00;
        let e = parse_event_packet(&big_endian)
            .expect_err("header")
            .to_string();
        assert!(e.contains("encapsulation 00 00"), "{e}");
        let a = parse_attachment(&attachment(5, 6, &[9; 16])).expect("attachment");
        assert_eq!((a.seq, a.source_ns, a.gid), (5, 6, [9; 16]));
        assert!(parse_attachment(&[0; 32]).is_err());
    }

    #[test]
    fn images_read_back_and_damage_is_named() {
        let bytes = image_cdr(-1, "cam", 2, 3, "mono8", 3, &[1, 2, 3, 4, 5, 6]);
        let img = parse_image(&bytes).expect("image");
        assert_eq!(
            (
                img.stamp_ns,
                img.frame_id.as_str(),
                img.height,
                img.width,
                img.step
            ),
            (-1, "cam", 2, 3, 3)
        );
        assert_eq!(
            (img.encoding.as_str(), img.data.clone()),
            ("mono8", vec![1, 2, 3, 4, 5, 6])
        );
        for cut in 0..bytes.len() {
            assert!(parse_image(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let short = image_cdr(0, "cam", 2, 3, "mono8", 4, &[1, 2, 3, 4, 5, 6]);
        let e = parse_image(&short).expect_err("2 rows of 4").to_string();
        assert!(
            e.contains("data of 6 bytes, 2 rows of 4 bytes need 8"),
            "{e}"
        );
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
        assert_eq!(
            node.subscriber_token(
                2,
                "/event_camera/events",
                EVENT_PACKET_TYPE,
                EVENT_PACKET_HASH
            ),
            format!(
                "@ros2_lv/0/ab12/0/2/MS/%/%/neuspike/%event_camera%events/{EVENT_PACKET_TYPE}/{EVENT_PACKET_HASH}/::,10:,:,:,,"
            )
        );
        assert_eq!(mangle("/a/b"), "%a%b");
    }
}
