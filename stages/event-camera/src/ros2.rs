//! A ROS 2 event camera as the source: `event_camera_msgs/msg/EventPacket` messages, as ROS 2
//! event-camera drivers (metavision_driver, libcaer_driver) publish them, taken over rmw_zenoh.
//!
//! - [`PacketDecoder`] (no network): each packet becomes one [`EventBatch`]. Encodings: `evt3`
//!   (Prophesee EVT 3.0 words, decoded by `neuspike_formats::evt3::Evt3Stream`, whose state
//!   carries from packet to packet as the driver's word stream does) and `mono` (64 bits an
//!   event: polarity bit 63, row bits 48-62, column bits 32-47, ns after `time_base` bits 0-31).
//!   The packets' `seq` numbers a lost packet: it is logged, counted, and a gap in the batches'
//!   sequence numbers, so the sink's summary counts it too. Batches tile time: each starts where
//!   the one before ended and ends at its packet's last event time, whose events wait for the
//!   next batch (the next packet may hold more at that time); the stream's end flushes them.
//! - [`RosEvents`]: the subscription on rmw_zenoh's key for the topic (any type hash), with the
//!   node's and the subscription's liveliness tokens, so that `ros2 topic info` counts it.

use std::time::{Duration, Instant};

use neuspike_formats::evt3::Evt3Stream;
use neuspike_formats::{EventBatch, ReadOptions, Resolution};
use neuspike_net::queue::BoundedSubscriber;
use neuspike_net::ros2::{
    self, EVENT_PACKET_HASH, EVENT_PACKET_TYPE, EventPacket, RosNode, parse_attachment,
    parse_event_packet,
};
use neuspike_schemas::Event;
use zenoh::Wait;

/// Why a ROS 2 event stream failed. Each names the topic and the packet.
#[derive(Debug, thiserror::Error)]
pub enum RosError {
    /// The subscription or its tokens could not be declared.
    #[error("{topic}: cannot subscribe: {reason}")]
    Subscribe {
        /// The topic.
        topic: String,
        /// zenoh's reason.
        reason: String,
    },
    /// Nothing arrived before the silence limit.
    #[error(
        "{topic}: no event packet arrived in {secs} s: no driver publishes it, or it cannot reach this node (see --connect/--listen)"
    )]
    Silent {
        /// The topic.
        topic: String,
        /// The limit, seconds.
        secs: u64,
    },
    /// A packet could not be read or decoded.
    #[error("{topic}: packet {n} (seq {seq}): {reason}")]
    Packet {
        /// The topic.
        topic: String,
        /// The packet's place in what arrived (from 0).
        n: u64,
        /// The packet's own `seq` (0 when unknown).
        seq: u64,
        /// What was wrong, with the value.
        reason: String,
    },
    /// Too many packets were malformed (see `neuspike_net::remote::BAD_SHARE`).
    #[error(
        "{topic}: {bad} of the {arrived} packets that arrived were malformed; the last: {last}"
    )]
    TooManyBad {
        /// The topic.
        topic: String,
        /// Malformed packets.
        bad: u64,
        /// Packets that arrived.
        arrived: u64,
        /// Why the last one was refused.
        last: String,
    },
    /// The session closed under the subscriber.
    #[error("{topic}: the zenoh session closed")]
    Closed {
        /// The topic.
        topic: String,
    },
}

enum Encoding {
    Evt3(Box<Evt3Stream>),
    Mono,
}

/// Packets in, batches out (see the module's documentation).
pub struct PacketDecoder {
    topic: String,
    size: Option<(u16, u16)>,
    encoding: Option<Encoding>,
    next_packet_seq: Option<u64>,
    lost_packets: u64,
    packets: u64,
    batches: u64,
    t_end_ns: Option<i64>,
    /// Events at the last time seen, held for the next batch.
    carry: EventBatch,
    /// Events dropped for coming at one instant past [`MAX_EVENTS_AT_ONE_INSTANT`].
    dropped_events: u64,
    /// Packet numbers that jumped past [`neuspike_schemas::MAX_SEQ_JUMP`] (a driver restarted,
    /// or a forgery): not counted as packets lost.
    seq_anomalies: u64,
}

/// The most events held at one instant, waiting for a later time to close their batch: 2^20,
/// more than every pixel of a 1280 x 720 sensor firing within one nanosecond. Past it, events at
/// that instant are dropped and counted ([`PacketDecoder::dropped_events`]), so a stream whose
/// time stands still cannot grow without bound.
pub const MAX_EVENTS_AT_ONE_INSTANT: usize = 1 << 20;

impl PacketDecoder {
    /// A decoder for the packets of `topic` (the name errors give).
    pub fn new(topic: &str) -> Self {
        PacketDecoder {
            topic: topic.to_string(),
            size: None,
            encoding: None,
            next_packet_seq: None,
            lost_packets: 0,
            packets: 0,
            batches: 0,
            t_end_ns: None,
            carry: EventBatch::default(),
            dropped_events: 0,
            seq_anomalies: 0,
        }
    }

    /// Events dropped for coming at one instant past [`MAX_EVENTS_AT_ONE_INSTANT`].
    pub fn dropped_events(&self) -> u64 {
        self.dropped_events
    }

    /// Packet numbers that jumped too far to be packets lost (not counted as lost).
    pub fn seq_anomalies(&self) -> u64 {
        self.seq_anomalies
    }

    /// Packets lost so far (gaps in their `seq`).
    pub fn lost_packets(&self) -> u64 {
        self.lost_packets
    }

    /// Packets taken so far.
    pub fn packets(&self) -> u64 {
        self.packets
    }

    fn error(&self, p: &EventPacket, reason: String) -> RosError {
        RosError::Packet {
            topic: self.topic.clone(),
            n: self.packets,
            seq: p.seq,
            reason,
        }
    }

    /// The batch of packet `p`, numbered after the batches before it.
    ///
    /// # Errors
    /// A sensor size that changed or does not fit 16 bits, an encoding other than `evt3` and
    /// `mono` (or one that changed), big-endian data, or events the encoding's decoder refuses
    /// (outside the sensor, time running backwards, damaged words).
    pub fn packet(&mut self, p: &EventPacket) -> Result<EventBatch, RosError> {
        let size = match (u16::try_from(p.width), u16::try_from(p.height)) {
            (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
            _ => {
                return Err(self.error(
                    p,
                    format!("sensor {}x{}: not a size in 1..=65535", p.width, p.height),
                ));
            }
        };
        neuspike_schemas::limits::check_sensor(
            "event packet",
            usize::from(size.0),
            usize::from(size.1),
        )
        .map_err(|e| self.error(p, e.to_string()))?;
        if let Some(s) = self.size
            && s != size
        {
            return Err(self.error(
                p,
                format!(
                    "sensor {}x{}, earlier packets said {}x{}",
                    size.0, size.1, s.0, s.1
                ),
            ));
        }
        if p.is_bigendian {
            return Err(self.error(p, "big-endian events are not supported".into()));
        }
        let mut encoding = match (self.encoding.take(), p.encoding.as_str()) {
            (Some(e @ Encoding::Evt3(_)), "evt3") => e,
            (Some(Encoding::Mono), "mono") => Encoding::Mono,
            (None, "evt3") => Encoding::Evt3(Box::new(Evt3Stream::new(
                format!("ros2:{}", self.topic),
                Resolution::new(size.0, size.1),
                &ReadOptions::default(),
            ))),
            (None, "mono") => Encoding::Mono,
            (previous, other) => {
                self.encoding = previous;
                return Err(self.error(
                    p,
                    format!(
                        "encoding {other:?}: this source reads `evt3` and `mono`, and the stream's first packet sets it"
                    ),
                ));
            }
        };
        self.size = Some(size);
        let mut out = EventBatch::empty(usize::from(size.0), usize::from(size.1), 0, 0, 0);
        self.carry.width = out.width;
        self.carry.height = out.height;
        let decoded = match &mut encoding {
            Encoding::Evt3(stream) => stream
                .decode(&p.events, &mut out)
                .map(|_| ())
                .map_err(|e| e.to_string()),
            Encoding::Mono => decode_mono(p, size, &mut out),
        };
        self.encoding = Some(encoding);
        decoded.map_err(|e| self.error(p, e))?;

        let mut anomaly = false;
        if let Some(next) = self.next_packet_seq
            && p.seq != next
        {
            if p.seq > next && p.seq - next > neuspike_schemas::MAX_SEQ_JUMP {
                anomaly = true;
                self.seq_anomalies += 1;
                tracing::warn!(topic = %self.topic, seq = p.seq, expected = next, "a packet number far past the stream's: not counted as packets lost");
            } else if p.seq > next {
                let lost = p.seq - next;
                self.lost_packets += lost;
                tracing::error!(topic = %self.topic, seq = p.seq, lost, "event packets lost before this one");
            } else {
                tracing::warn!(topic = %self.topic, seq = p.seq, expected = next, "the driver's packet numbers went back");
            }
        }
        // A number far ahead leaves the expected one where it was: the genuine packets after
        // it are not taken as going back.
        if !anomaly {
            self.next_packet_seq = Some(p.seq.wrapping_add(1));
        }
        self.packets += 1;

        // The interval: from where the last batch ended (or the first event, or the packet's
        // stamp) to this packet's last event time, exclusive. Events at that time wait for the
        // next batch: the next packet may hold more of them.
        let first = self.carry.t_ns.first().or(out.t_ns.first()).copied();
        let start = self.t_end_ns.or(first).unwrap_or(p.stamp_ns);
        if let (Some(t), Some(floor)) = (out.t_ns.first().copied(), self.t_end_ns)
            && t < floor
        {
            return Err(self.error(
                p,
                format!(
                    "its first event at t_ns {t} is earlier than the previous packet's last, at {floor}"
                ),
            ));
        }
        let mut events = std::mem::replace(
            &mut self.carry,
            EventBatch::empty(out.width, out.height, 0, 0, 0),
        );
        for i in 0..out.len() {
            events.push(out.get(i));
        }
        let end = events.t_ns.last().copied().unwrap_or(start).max(start);
        let keep = events.t_ns.partition_point(|&t| t < end);
        let held = events.len() - keep;
        let room = MAX_EVENTS_AT_ONE_INSTANT.min(held);
        for i in keep..keep + room {
            self.carry.push(events.get(i));
        }
        if held > room {
            let dropped = (held - room) as u64;
            self.dropped_events += dropped;
            tracing::warn!(topic = %self.topic, dropped, t_ns = end, "more events at one instant than a sensor makes: dropped");
        }
        events.truncate(keep);
        Ok(self.numbered(events, start, end))
    }

    /// The events held back at the last time seen, as the stream's final batch (`None` when
    /// none are).
    pub fn flush(&mut self) -> Option<EventBatch> {
        let last = self.carry.t_ns.last().copied()?;
        let start = self.t_end_ns.unwrap_or(last);
        let empty = EventBatch::empty(self.carry.width, self.carry.height, 0, 0, 0);
        let events = std::mem::replace(&mut self.carry, empty);
        Some(self.numbered(events, start, last.saturating_add(1)))
    }

    fn numbered(&mut self, mut batch: EventBatch, start: i64, end: i64) -> EventBatch {
        batch.t_start_ns = start;
        batch.t_end_ns = end;
        // Numbered so that a lost packet is a gap downstream too.
        batch.seq = self.batches.saturating_add(self.lost_packets);
        self.batches += 1;
        self.t_end_ns = Some(end);
        batch
    }
}

/// The `mono` encoding: 8 bytes an event, little-endian; polarity bit 63, row bits 48-62, column
/// bits 32-47, ns after `time_base` bits 0-31.
fn decode_mono(p: &EventPacket, size: (u16, u16), out: &mut EventBatch) -> Result<(), String> {
    if !p.events.len().is_multiple_of(8) {
        return Err(format!(
            "`mono` events of {} bytes, not a multiple of 8",
            p.events.len()
        ));
    }
    let base = i64::try_from(p.time_base)
        .map_err(|_| format!("time_base {} does not fit a time in ns", p.time_base))?;
    let mut last = i64::MIN;
    for (i, w) in p.events.chunks_exact(8).enumerate() {
        let mut b = [0u8; 8];
        b.copy_from_slice(w);
        let v = u64::from_le_bytes(b);
        let on = v >> 63 == 1;
        let y = ((v >> 48) & 0x7FFF) as u32;
        let x = ((v >> 32) & 0xFFFF) as u32;
        let t = base.saturating_add((v & 0xFFFF_FFFF) as i64);
        if x >= u32::from(size.0) || y >= u32::from(size.1) {
            return Err(format!(
                "event {i} at ({x}, {y}) is outside the {}x{} sensor",
                size.0, size.1
            ));
        }
        if t < last {
            return Err(format!(
                "event {i} at t_ns {t} is earlier than event {} at {last}",
                i - 1
            ));
        }
        last = t;
        out.push(Event {
            t_ns: t,
            x: x as u16,
            y: y as u16,
            polarity: if on { 1 } else { -1 },
        });
    }
    Ok(())
}

/// What [`RosEvents::next`] took.
#[derive(Debug)]
pub enum RosTaken {
    /// A packet's batch, with the time the driver published it (from its attachment), ns since
    /// the epoch.
    Batch(EventBatch, Option<i64>),
    /// The driver went quiet for the silence limit after sending: the stream ends.
    End,
    /// Nothing yet.
    Idle,
}

/// A ROS 2 event topic, subscribed over rmw_zenoh.
pub struct RosEvents {
    topic: String,
    sub: BoundedSubscriber,
    decoder: PacketDecoder,
    /// The publisher followed, by its GID.
    owner: neuspike_net::remote::Follower<Option<[u8; 16]>>,
    malformed: u64,
    arrived: u64,
    silence: Duration,
    last: Instant,
    _tokens: [zenoh::liveliness::LivelinessToken; 2],
}

impl RosEvents {
    /// Subscribes to `topic` in ROS domain `domain` on `session` as node `node`. Before the
    /// first packet, `silence` without one is an error; after it, the end of the stream.
    ///
    /// # Errors
    /// zenoh refused the subscription or a token.
    pub fn subscribe(
        session: &zenoh::Session,
        topic: &str,
        domain: u32,
        node: &str,
        silence: Duration,
    ) -> Result<Self, RosError> {
        let err = |e: zenoh::Error| RosError::Subscribe {
            topic: topic.to_string(),
            reason: e.to_string(),
        };
        let ros = RosNode {
            domain,
            zid: session.zid().to_string(),
            node_id: 0,
            namespace: "/".into(),
            name: node.to_string(),
        };
        // Any type hash: drivers built against other message versions are still read, and a
        // packet that is not an EventPacket fails to parse with its packet named.
        let key = format!(
            "{domain}/{}/{EVENT_PACKET_TYPE}/*",
            ros2::strip_topic(topic)
        );
        let sub = BoundedSubscriber::declare(session, &key).map_err(err)?;
        let node_token = session
            .liveliness()
            .declare_token(ros.node_token())
            .wait()
            .map_err(err)?;
        let sub_token = session
            .liveliness()
            .declare_token(ros.subscriber_token(1, topic, EVENT_PACKET_TYPE, EVENT_PACKET_HASH))
            .wait()
            .map_err(err)?;
        Ok(RosEvents {
            topic: topic.to_string(),
            sub,
            decoder: PacketDecoder::new(topic),
            owner: neuspike_net::remote::Follower::default(),
            malformed: 0,
            arrived: 0,
            silence,
            last: Instant::now(),
            _tokens: [node_token, sub_token],
        })
    }

    /// The packets' decoder (its counts).
    pub fn decoder(&self) -> &PacketDecoder {
        &self.decoder
    }

    /// Waits up to `wait` for the next packet.
    ///
    /// # Errors
    /// Silence before the first packet, a packet that cannot be read or decoded, or the session
    /// closed.
    pub fn next(&mut self, wait: Duration) -> Result<RosTaken, RosError> {
        loop {
            let Some(sample) = self.sub.recv_timeout(wait) else {
                if self.last.elapsed() < self.silence {
                    return Ok(RosTaken::Idle);
                }
                if self.decoder.packets() > 0 {
                    if let Some(last) = self.decoder.flush() {
                        return Ok(RosTaken::Batch(last, None));
                    }
                    tracing::info!(topic = %self.topic, packets = self.decoder.packets(), lost = self.decoder.lost_packets(), foreign = self.owner.foreign(), malformed = self.malformed, "no packet for {} s: the stream ends", self.silence.as_secs());
                    return Ok(RosTaken::End);
                }
                return Err(RosError::Silent {
                    topic: self.topic.clone(),
                    secs: self.silence.as_secs(),
                });
            };
            let attachment = sample
                .attachment()
                .and_then(|a| parse_attachment(&a.to_bytes()).ok());
            if !self.follows(attachment.as_ref().map(|a| a.gid)) {
                continue;
            }
            self.last = Instant::now();
            self.arrived += 1;
            let n = self.decoder.packets();
            let origin = attachment.map(|a| a.source_ns);
            let decoded = parse_event_packet(&sample.payload().to_bytes())
                .map_err(|e| RosError::Packet {
                    topic: self.topic.clone(),
                    n,
                    seq: 0,
                    reason: e.to_string(),
                })
                .and_then(|packet| self.decoder.packet(&packet));
            match decoded {
                Ok(batch) => return Ok(RosTaken::Batch(batch, origin)),
                Err(e) => self.reject(e)?,
            }
        }
    }

    /// Packets refused for coming from a publisher other than the one the stream follows.
    pub fn foreign(&self) -> u64 {
        self.owner.foreign()
    }

    /// Lets another publisher take the topic once the followed one has been silent for `after`
    /// ([`neuspike_net::remote::Follower::rejoining_after`]; 2 s unless set).
    #[must_use]
    pub fn rejoining_after(mut self, after: Duration) -> Self {
        self.owner = neuspike_net::remote::Follower::rejoining_after(after);
        self
    }

    /// Packets refused as malformed.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    /// Whether a packet from the publisher with `gid` (from its rmw_zenoh attachment; `None`
    /// without one) is the stream's ([`neuspike_net::remote::Follower`]).
    fn follows(&mut self, gid: Option<[u8; 16]>) -> bool {
        self.owner.follows(gid, &self.topic)
    }

    /// Counts a malformed packet and drops it; the stream fails once more than
    /// [`neuspike_net::remote::BAD_GRACE`] packets, and more than
    /// [`neuspike_net::remote::BAD_SHARE`] of all that arrived, were malformed.
    fn reject(&mut self, why: RosError) -> Result<(), RosError> {
        self.malformed += 1;
        tracing::warn!(topic = %self.topic, "{why}: dropped");
        if neuspike_net::remote::too_many_bad(self.malformed, self.arrived) {
            return Err(RosError::TooManyBad {
                topic: self.topic.clone(),
                bad: self.malformed,
                arrived: self.arrived,
                last: why.to_string(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn packet(seq: u64, encoding: &str, events: Vec<u8>) -> EventPacket {
        EventPacket {
            stamp_ns: 0,
            frame_id: "dvs".into(),
            height: 30,
            width: 40,
            seq,
            time_base: 1_000_000,
            encoding: encoding.into(),
            is_bigendian: false,
            events,
        }
    }

    fn mono(t: u32, x: u16, y: u16, on: bool) -> [u8; 8] {
        (u64::from(on) << 63 | u64::from(y) << 48 | u64::from(x) << 32 | u64::from(t)).to_le_bytes()
    }

    #[test]
    fn a_stream_whose_time_stands_still_holds_a_bounded_number_of_events() {
        let mut d = PacketDecoder::new("/dvs/events");
        let per = 4096;
        let events: Vec<u8> = (0..per)
            .flat_map(|i| mono(7, (i % 40) as u16, (i / 40 % 30) as u16, true))
            .collect();
        let packets = MAX_EVENTS_AT_ONE_INSTANT / per + 3;
        for seq in 0..packets as u64 {
            let b = d
                .packet(&packet(seq, "mono", events.clone()))
                .expect("packet");
            assert_eq!(b.len(), 0, "every event waits for a later time");
        }
        assert_eq!(d.carry.len(), MAX_EVENTS_AT_ONE_INSTANT);
        assert_eq!(
            d.dropped_events(),
            (packets * per - MAX_EVENTS_AT_ONE_INSTANT) as u64
        );
    }

    #[test]
    fn a_packet_number_far_ahead_is_not_counted_as_packets_lost() {
        let mut d = PacketDecoder::new("/dvs/events");
        d.packet(&packet(0, "mono", mono(1, 0, 0, true).to_vec()))
            .expect("first");
        let b = d
            .packet(&packet(1 << 63, "mono", mono(2, 0, 0, true).to_vec()))
            .expect("far ahead");
        assert_eq!((d.lost_packets(), d.seq_anomalies(), b.seq), (0, 1, 1));
        let b = d
            .packet(&packet(1, "mono", mono(3, 0, 0, true).to_vec()))
            .expect("genuine");
        assert_eq!((d.lost_packets(), b.seq), (0, 2));
    }

    #[test]
    fn a_packet_claiming_a_sensor_past_the_pixel_limit_is_refused() {
        let mut d = PacketDecoder::new("/dvs/events");
        let mut p = packet(0, "mono", vec![]);
        p.width = 65_535;
        p.height = 65_535;
        let e = d.packet(&p).expect_err("too big").to_string();
        assert!(
            e.contains("/dvs/events") && e.contains("65535x65535"),
            "{e}"
        );
    }

    #[test]
    fn mono_packets_become_batches_that_tile_time_and_lost_packets_are_counted() {
        let mut d = PacketDecoder::new("/dvs/events");
        let b = d
            .packet(&packet(
                5,
                "mono",
                [mono(10, 1, 2, true), mono(20, 39, 29, false)].concat(),
            ))
            .expect("packet");
        // The last time's events wait: the next packet may hold more at that time.
        assert_eq!(b.t_ns, [1_000_010]);
        assert_eq!(
            (b.x.clone(), b.y.clone(), b.polarity.clone()),
            (vec![1], vec![2], vec![1])
        );
        assert_eq!((b.t_start_ns, b.t_end_ns, b.seq), (1_000_010, 1_000_020, 0));
        // Packet 6 lost; 7 is empty and still moves nothing back.
        let b = d.packet(&packet(7, "mono", vec![])).expect("empty");
        assert_eq!(
            (b.t_start_ns, b.t_end_ns, b.seq, b.len()),
            (1_000_020, 1_000_020, 2, 0),
            "seq 1 lost"
        );
        assert_eq!(d.lost_packets(), 1);
        let b = d
            .packet(&packet(8, "mono", mono(20, 3, 4, false).to_vec()))
            .expect("same time");
        assert_eq!(b.len(), 0, "both events at 1_000_020 still wait");
        let last = d.flush().expect("the held events");
        assert_eq!(last.t_ns, [1_000_020, 1_000_020]);
        assert_eq!(
            (last.x.clone(), last.polarity.clone()),
            (vec![39, 3], vec![-1, -1])
        );
        assert_eq!(
            (last.t_start_ns, last.t_end_ns, last.seq),
            (1_000_020, 1_000_021, 4)
        );
        assert!(d.flush().is_none());
        let e = d
            .packet(&packet(9, "mono", mono(50, 40, 0, true).to_vec()))
            .expect_err("outside")
            .to_string();
        assert!(
            e.contains("/dvs/events") && e.contains("(40, 0) is outside the 40x30"),
            "{e}"
        );
        let e = d
            .packet(&packet(10, "evt3", vec![]))
            .expect_err("encoding changed")
            .to_string();
        assert!(e.contains("\"evt3\""), "{e}");
        let mut big = packet(11, "mono", vec![]);
        big.width = 41;
        assert!(
            d.packet(&big)
                .expect_err("size changed")
                .to_string()
                .contains("earlier packets said 40x30")
        );
    }

    #[test]
    fn evt3_packets_carry_the_decoders_state_from_one_to_the_next() {
        let mut whole = EventBatch::empty(40, 30, 0, 1_000_000_000, 0);
        for i in 0..200i64 {
            whole.push(Event {
                t_ns: 1_000 * (3 * i),
                x: (i % 40) as u16,
                y: (i % 30) as u16,
                polarity: if i % 2 == 0 { 1 } else { -1 },
            });
        }
        let words =
            neuspike_formats::evt3::packet_words(&whole, Resolution::new(40, 30)).expect("words");
        let mut d = PacketDecoder::new("/events");
        let mut got = Vec::new();
        let mut last_end = None;
        for (i, piece) in words.chunks(64).enumerate() {
            let b = d
                .packet(&packet(i as u64, "evt3", piece.to_vec()))
                .expect("packet");
            if let Some(e) = last_end {
                assert_eq!(b.t_start_ns, e, "batches tile time");
            }
            last_end = Some(b.t_end_ns);
            got.extend_from_slice(&b.t_ns);
        }
        let last = d.flush().expect("the last time's events");
        assert_eq!(last.t_start_ns, last_end.expect("batches"));
        got.extend_from_slice(&last.t_ns);
        assert_eq!(got, whole.t_ns);
        assert_eq!(d.lost_packets(), 0);
    }
}
