//! neuspike's messages from a zenoh key: a camera on another machine, as its `neuspike
//! publish-file` or a graph's publish node sends it.
//!
//! Every sample is one message as Arrow IPC ([`neuspike_schemas::ipc`]). [`Remote`] checks its
//! type, follows its sequence numbers (a gap is messages lost on the way: logged and counted,
//! never silent; a duplicate is dropped), and ends at the stream's end-of-stream marker. A key
//! on which nothing arrives for the silence limit is an error that names it, so a source whose
//! camera vanished ends instead of waiting forever.
//!
//! The subscriber's queue is bounded in samples and in bytes ([`crate::queue`]); when it is full
//! zenoh stops reading the link, so a publisher that sends with congestion control `block`
//! (neuspike's do) is held back rather than losing messages.

use std::time::{Duration, Instant};

use crate::queue::BoundedSubscriber;
use neuspike_schemas::arrow::array::ArrayRef;
use neuspike_schemas::ipc::{self, IpcError};
use neuspike_schemas::{Meta, MetaExt, SeqStatus, SeqTracker, is_end_of_stream};
use zenoh::Wait;
use zenoh::sample::Sample;
use zenoh::session::EntityGlobalId;

/// How long the publisher a stream follows must have been silent before another may take its
/// place (a camera restarted as a new process, with a new identity).
pub const REJOIN_AFTER: Duration = Duration::from_secs(2);

/// Malformed samples a stream may take before [`BAD_SHARE`] applies: a few bad samples (a
/// stray publisher, one damaged message) are counted and dropped, never the end of a camera.
pub const BAD_GRACE: u64 = 16;

/// The share of the samples that arrived which may be malformed (past [`BAD_GRACE`]) before the
/// stream fails: beyond it the key is carrying something else, and saying so beats dropping.
pub const BAD_SHARE: f64 = 0.05;

/// What [`Remote::next`] took.
#[derive(Debug)]
pub enum Taken {
    /// The next message, in order: its header and payload.
    Message(Meta, ArrayRef),
    /// The stream's end: the messages its publisher sent, and whether its stream was cut short
    /// upstream.
    End {
        /// Messages before the marker.
        count: u64,
        /// The stream was cut short where it was made.
        cut: bool,
    },
    /// Nothing yet (the wait was up); ask again.
    Idle,
}

/// Why a remote stream failed.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    /// The subscription could not be made.
    #[error("cannot subscribe to {key}: {reason}")]
    Subscribe {
        /// The key.
        key: String,
        /// zenoh's reason.
        reason: String,
    },
    /// Nothing arrived for too long.
    #[error(
        "{key}: nothing arrived for {secs} s ({received} messages received before): the publisher is gone or cannot reach this node (see --connect/--listen)"
    )]
    Silent {
        /// The key.
        key: String,
        /// The limit, seconds.
        secs: f64,
        /// Messages received before the silence.
        received: u64,
    },
    /// A sample is not one of neuspike's messages.
    #[error("{key}: sample {n} is not a neuspike message: {source}")]
    Decode {
        /// The key.
        key: String,
        /// The sample's place in what arrived (from 0).
        n: u64,
        /// Why.
        source: IpcError,
    },
    /// A message of another type.
    #[error("{key}: sample {n} is a {found}, this source takes {expected}")]
    Type {
        /// The key.
        key: String,
        /// The sample's place in what arrived (from 0).
        n: u64,
        /// The type taken.
        expected: &'static str,
        /// The type found.
        found: String,
    },
    /// A message without a sequence number.
    #[error("{key}: sample {n}: {reason}")]
    Header {
        /// The key.
        key: String,
        /// The sample's place in what arrived (from 0).
        n: u64,
        /// Why.
        reason: String,
    },
    /// Too many samples were malformed: more than [`BAD_GRACE`], and more than [`BAD_SHARE`]
    /// of all that arrived.
    #[error("{key}: {bad} of the {arrived} samples that arrived were malformed; the last: {last}")]
    TooManyBad {
        /// The key.
        key: String,
        /// Malformed samples.
        bad: u64,
        /// Samples that arrived.
        arrived: u64,
        /// Why the last one was refused.
        last: String,
    },
    /// The session closed under the subscriber.
    #[error("{key}: the zenoh session closed")]
    Closed {
        /// The key.
        key: String,
    },
}

/// The wall-clock time a message's newest camera data left its source, as the sending graph
/// stamped it (`origin_unix_ns`), if it did.
pub fn origin(meta: &Meta) -> Option<i64> {
    match meta.get(neuspike_schemas::meta::ORIGIN_UNIX_NS) {
        Some(neuspike_schemas::Parameter::Integer(t)) => Some(*t),
        _ => None,
    }
}

/// Puts `bytes` (one message) on `publisher` with its source identity (the publisher's
/// `EntityGlobalId`) and `sn`, the publisher's count of what it put: what a [`Remote`] follows.
///
/// # Errors
/// zenoh refused the put.
pub fn put_message(
    publisher: &zenoh::pubsub::Publisher<'_>,
    bytes: Vec<u8>,
    sn: u32,
) -> zenoh::Result<()> {
    use zenoh::sample::SourceInfo;
    publisher
        .put(bytes)
        .source_info(SourceInfo::new(publisher.id(), sn))
        .wait()
}

/// The publisher a stream follows, by its identity `Id` (a zenoh source identity, a ROS 2 GID;
/// `None` inside for one that sends none): the first one, or, once that one has been silent for
/// [`REJOIN_AFTER`], whoever sends next (a restarted camera). Samples from anyone else are
/// counted and refused: they can neither end the stream nor move its sequence.
#[derive(Debug)]
pub struct Follower<Id> {
    owner: Option<(Id, Instant)>,
    foreign: u64,
    rejoin_after: Duration,
    /// The last sample followed came from a new publisher, after another.
    switched: bool,
}

impl<Id> Default for Follower<Id> {
    fn default() -> Self {
        Follower::rejoining_after(REJOIN_AFTER)
    }
}

impl<Id> Follower<Id> {
    /// A follower that lets another publisher take the stream once the followed one has been
    /// silent for `rejoin_after`: [`REJOIN_AFTER`], or zero where the link authenticates
    /// every publisher ([`crate::session::ZenohArgs::authenticates`]: whoever may publish is the
    /// camera, and a restarted one rejoins at once).
    pub fn rejoining_after(rejoin_after: Duration) -> Self {
        Follower {
            owner: None,
            foreign: 0,
            rejoin_after,
            switched: false,
        }
    }

    /// Whether the last sample followed came from a new publisher taking over from another
    /// (cleared by asking): its numbering may start afresh.
    pub fn take_switched(&mut self) -> bool {
        std::mem::take(&mut self.switched)
    }

    /// Samples refused for coming from another publisher.
    pub fn foreign(&self) -> u64 {
        self.foreign
    }
}

impl<Id: PartialEq + std::fmt::Debug> Follower<Id> {
    /// Whether a sample from `id` is the stream's (`stream` names it in the logs).
    pub fn follows(&mut self, id: Id, stream: &str) -> bool {
        let now = Instant::now();
        match &mut self.owner {
            Some((owner, last)) if *owner == id => {
                *last = now;
                true
            }
            Some((owner, last)) if now.duration_since(*last) < self.rejoin_after => {
                self.foreign += 1;
                tracing::warn!(stream, from = ?id, following = ?owner, "a sample from another publisher: refused");
                false
            }
            previous => {
                if let Some((old, _)) = previous {
                    tracing::warn!(stream, from = ?id, was = ?old, "the publisher went silent; following the new one");
                    self.switched = true;
                }
                *previous = Some((id, now));
                true
            }
        }
    }
}

/// Whether `bad` malformed samples out of `arrived` are too many for a stream to go on: more than
/// [`BAD_GRACE`], and more than [`BAD_SHARE`] of them.
pub fn too_many_bad(bad: u64, arrived: u64) -> bool {
    bad > BAD_GRACE && bad as f64 > BAD_SHARE * arrived as f64
}

/// A stream of neuspike messages of one type on one zenoh key.
pub struct Remote {
    key: String,
    expected: &'static str,
    sub: BoundedSubscriber,
    seq: SeqTracker,
    arrived: u64,
    /// Samples refused as malformed.
    malformed: u64,
    /// The publisher the stream follows, by its zenoh source identity.
    owner: Follower<Option<EntityGlobalId>>,
    silence: Duration,
    last: Instant,
    /// Set once the first message came.
    started: bool,
}

impl Remote {
    /// Subscribes to `key` on `session`, for messages of type `expected` (a `TYPE_URN`); the
    /// stream fails after `silence` without a sample (before the first one too).
    ///
    /// # Errors
    /// zenoh refused the subscription (a malformed key).
    pub fn subscribe(
        session: &zenoh::Session,
        key: &str,
        expected: &'static str,
        silence: Duration,
    ) -> Result<Self, RemoteError> {
        let sub = BoundedSubscriber::declare(session, key).map_err(|e| RemoteError::Subscribe {
            key: key.to_string(),
            reason: e.to_string(),
        })?;
        Ok(Remote {
            key: key.to_string(),
            expected,
            sub,
            seq: SeqTracker::default(),
            arrived: 0,
            malformed: 0,
            owner: Follower::default(),
            silence,
            last: Instant::now(),
            started: false,
        })
    }

    /// The key.
    pub fn key(&self) -> &str {
        &self.key
    }

    /// Messages lost on the way so far (gaps in the sequence numbers, the tail included once
    /// the marker came).
    pub fn missing(&self) -> u64 {
        self.seq.missing()
    }

    /// Messages received (duplicates not counted).
    pub fn received(&self) -> u64 {
        self.seq.received()
    }

    /// Messages refused, not lost: a sequence number far past the stream's, or an end
    /// announcing far too many ([`neuspike_schemas::SeqStatus::Anomaly`]).
    pub fn refused(&self) -> u64 {
        self.seq.anomalies()
    }

    /// Samples refused for coming from a publisher other than the one the stream follows.
    pub fn foreign(&self) -> u64 {
        self.owner.foreign()
    }

    /// Whether the sample comes from the publisher the stream follows: the first one, or, once
    /// that one has been silent for [`REJOIN_AFTER`], whoever sends next (a restarted camera).
    /// A sample from anyone else is counted and refused: it can neither end the stream nor move
    /// its sequence.
    fn follows(&mut self, sample: &Sample) -> bool {
        let id = sample.source_info().map(|s| *s.source_id());
        let follows = self.owner.follows(id, &self.key);
        if self.owner.take_switched() {
            // A restarted camera may number from 0 again: followed, not taken as stale.
            self.seq.rejoin();
        }
        follows
    }

    /// Lets another publisher take the stream once the followed one has been silent for
    /// `after` ([`Follower::rejoining_after`]; [`REJOIN_AFTER`] unless set).
    #[must_use]
    pub fn rejoining_after(mut self, after: Duration) -> Self {
        self.owner = Follower::rejoining_after(after);
        self
    }

    /// Times a new publisher took the stream numbering afresh (a restarted camera).
    pub fn restarts(&self) -> u64 {
        self.seq.restarts()
    }

    /// Samples refused as malformed: not a neuspike message, another type, no sequence number,
    /// or a payload its reader refused ([`Remote::reject`]).
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    /// Counts a malformed sample (`why`) and drops it; the stream fails once more than
    /// [`BAD_GRACE`] samples, and more than [`BAD_SHARE`] of all that arrived, were malformed.
    ///
    /// # Errors
    /// [`RemoteError::TooManyBad`], naming the key, the counts and `why`.
    pub fn reject(&mut self, why: RemoteError) -> Result<(), RemoteError> {
        self.malformed += 1;
        tracing::warn!(key = %self.key, "{why}: dropped");
        if too_many_bad(self.malformed, self.arrived) {
            return Err(RemoteError::TooManyBad {
                key: self.key.clone(),
                bad: self.malformed,
                arrived: self.arrived,
                last: why.to_string(),
            });
        }
        Ok(())
    }

    /// Waits up to `wait` for the next message.
    ///
    /// # Errors
    /// A sample that is not a message of the expected type, a message without a sequence
    /// number, silence beyond the limit, or the session closed.
    pub fn next(&mut self, wait: Duration) -> Result<Taken, RemoteError> {
        loop {
            let Some(sample) = self.sub.recv_timeout(wait) else {
                if self.last.elapsed() >= self.silence {
                    return Err(RemoteError::Silent {
                        key: self.key.clone(),
                        secs: self.silence.as_secs_f64(),
                        received: self.seq.received(),
                    });
                }
                return Ok(Taken::Idle);
            };
            if !self.follows(&sample) {
                continue;
            }
            self.last = Instant::now();
            let n = self.arrived;
            self.arrived += 1;
            let bytes = sample.payload().to_bytes();
            let (urn, meta, data) = match ipc::decode(&bytes) {
                Ok(m) => m,
                Err(source) => {
                    self.reject(RemoteError::Decode {
                        key: self.key.clone(),
                        n,
                        source,
                    })?;
                    continue;
                }
            };
            if urn != self.expected {
                self.reject(RemoteError::Type {
                    key: self.key.clone(),
                    n,
                    expected: self.expected,
                    found: urn,
                })?;
                continue;
            }
            if let Some(count) = is_end_of_stream(&meta) {
                let lost = self.seq.end(count);
                if lost > 0 {
                    tracing::error!(key = %self.key, lost, "messages lost on the network at the end of the stream");
                }
                return Ok(Taken::End {
                    count,
                    cut: meta.flag(neuspike_schemas::meta::CUT),
                });
            }
            let seq = match meta.uint("message", neuspike_schemas::meta::SEQ) {
                Ok(seq) => seq,
                Err(e) => {
                    self.reject(RemoteError::Header {
                        key: self.key.clone(),
                        n,
                        reason: e.to_string(),
                    })?;
                    continue;
                }
            };
            match self.seq.observe(seq) {
                SeqStatus::InOrder => {}
                SeqStatus::Gap { missing } => {
                    tracing::error!(key = %self.key, seq, missing, "messages lost on the network before this one");
                }
                SeqStatus::Stale => {
                    tracing::warn!(key = %self.key, seq, "a message at or before one already taken: dropped");
                    continue;
                }
                SeqStatus::Anomaly { jump } => {
                    tracing::warn!(key = %self.key, seq, jump, "a sequence number far past the stream's: refused");
                    continue;
                }
                SeqStatus::Resynced { jump } => {
                    tracing::warn!(key = %self.key, seq, jump, "the remote stream was renumbered: following it");
                }
                SeqStatus::Restarted { expected } => {
                    tracing::warn!(key = %self.key, seq, expected, "the camera restarted and numbers afresh: following it");
                }
            }
            if !self.started {
                self.started = true;
                tracing::info!(key = %self.key, seq, "the remote stream started");
            }
            return Ok(Taken::Message(meta, data));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::arrow::array::UInt8Array;
    use neuspike_schemas::{Message, Parameter, SpikeChunk, end_of_stream};
    use std::sync::Arc;

    fn session(listen: &str, connect: &str) -> zenoh::Session {
        let mut c = zenoh::Config::default();
        c.insert_json5("mode", "\"peer\"").expect("mode");
        c.insert_json5("listen/endpoints", &format!("[\"{listen}\"]"))
            .expect("listen");
        c.insert_json5("connect/endpoints", &format!("[{connect}]"))
            .expect("connect");
        c.insert_json5("scouting/multicast/enabled", "false")
            .expect("scouting");
        zenoh::open(c).wait().expect("session")
    }

    fn chunk(seq: u64) -> (Meta, ArrayRef) {
        let c = SpikeChunk {
            width: 8,
            height: 1,
            first_plane: seq,
            n_planes: 1,
            t_first_ns: 0,
            plane_period_ns: 50_000,
            seq,
            bits: vec![seq as u8],
            lum_per_rate: None,
        };
        c.to_arrow()
    }

    /// The error the stream ends with (it must end with one).
    fn next_error(r: &mut Remote) -> String {
        loop {
            match r.next(Duration::from_millis(100)) {
                Ok(Taken::Idle) => {}
                Ok(other) => panic!("{other:?}"),
                Err(e) => return e.to_string(),
            }
        }
    }

    fn next_taken(r: &mut Remote) -> Taken {
        for _ in 0..50 {
            match r.next(Duration::from_millis(100)).expect("next") {
                Taken::Idle => {}
                t => return t,
            }
        }
        panic!("nothing arrived");
    }

    /// A publisher on `key` of `s`, once a subscriber matched it.
    fn matched_publisher<'a>(s: &'a zenoh::Session, key: &str) -> zenoh::pubsub::Publisher<'a> {
        let p = s
            .declare_publisher(key.to_string())
            .wait()
            .expect("publisher");
        let deadline = Instant::now() + Duration::from_secs(10);
        while !p.matching_status().wait().expect("status").matching() {
            assert!(Instant::now() < deadline, "the subscriber never matched");
            std::thread::sleep(Duration::from_millis(20));
        }
        p
    }

    /// Puts a spike chunk (or its end marker) on `p`, as neuspike's publishers do.
    fn put(p: &zenoh::pubsub::Publisher<'_>, (m, d): (Meta, ArrayRef)) {
        let bytes = ipc::encode(SpikeChunk::TYPE_URN, &m, &d).expect("encode");
        put_message(p, bytes, 0).expect("put");
    }

    #[test]
    fn gaps_are_counted_duplicates_dropped_and_the_end_says_how_many_were_sent() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("port")
            .port();
        let a = session(&format!("tcp/127.0.0.1:{port}"), "");
        let b = session("tcp/127.0.0.1:0", &format!("\"tcp/127.0.0.1:{port}\""));
        let mut remote = Remote::subscribe(
            &a,
            "test/spikes",
            SpikeChunk::TYPE_URN,
            Duration::from_secs(10),
        )
        .expect("subscribe");
        let publisher = b
            .declare_publisher("test/spikes")
            .wait()
            .expect("publisher");
        let deadline = Instant::now() + Duration::from_secs(10);
        while !publisher
            .matching_status()
            .wait()
            .expect("status")
            .matching()
        {
            assert!(Instant::now() < deadline, "the subscriber never matched");
            std::thread::sleep(Duration::from_millis(20));
        }
        let put = |urn: &str, (m, d): (Meta, ArrayRef)| {
            put_message(&publisher, ipc::encode(urn, &m, &d).expect("encode"), 0).expect("put");
        };
        for seq in [0, 1, 3, 3] {
            put(SpikeChunk::TYPE_URN, chunk(seq));
        }
        // A forged number far ahead is refused, and blinds nothing: 4 still comes through.
        let (mut forged, d) = chunk(4);
        forged.insert("seq".into(), Parameter::Integer(1 << 62));
        put(SpikeChunk::TYPE_URN, (forged, d));
        put(SpikeChunk::TYPE_URN, chunk(4));
        let (mut eos, d) = end_of_stream::<SpikeChunk>(6);
        eos.insert("cut".into(), Parameter::Bool(true));
        put(SpikeChunk::TYPE_URN, (eos, d));
        let mut seqs = Vec::new();
        loop {
            match next_taken(&mut remote) {
                Taken::Message(m, d) => {
                    seqs.push(SpikeChunk::from_arrow(&m, &d).expect("chunk").seq);
                }
                Taken::End { count, cut } => {
                    assert_eq!((count, cut), (6, true));
                    break;
                }
                Taken::Idle => unreachable!(),
            }
        }
        assert_eq!(
            seqs,
            [0, 1, 3, 4],
            "the duplicate and the forgery are dropped"
        );
        assert_eq!(
            (remote.received(), remote.missing(), remote.refused()),
            (4, 2, 1),
            "seq 2 and seq 5 lost, the forgery refused"
        );

        // Another type, or bytes that are not a message, are counted and dropped...
        let bytes: ArrayRef = Arc::new(UInt8Array::from(vec![1u8]));
        let mut m = Meta::new();
        m.insert("seq".into(), Parameter::Integer(9));
        put("neuspike/messages/v1/Frame", (m.clone(), bytes.clone()));
        put_message(&publisher, b"not arrow".to_vec(), 0).expect("put");
        let deadline = Instant::now() + Duration::from_secs(10);
        while remote.malformed() < 2 {
            assert!(Instant::now() < deadline, "the bad samples never came");
            assert!(matches!(
                remote.next(Duration::from_millis(50)).expect("still going"),
                Taken::Idle
            ));
        }
        // ... until they are too many: then the stream fails, naming the key and the last.
        for _ in 0..BAD_GRACE {
            put("neuspike/messages/v1/Frame", (m.clone(), bytes.clone()));
        }
        let e = next_error(&mut remote);
        assert!(
            e.starts_with("test/spikes: 17 of the ")
                && e.contains("is a neuspike/messages/v1/Frame"),
            "{e}"
        );
    }

    #[test]
    fn a_stream_follows_its_first_publisher_and_refuses_the_others() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("port")
            .port();
        let a = session(&format!("tcp/127.0.0.1:{port}"), "");
        let camera = session("tcp/127.0.0.1:0", &format!("\"tcp/127.0.0.1:{port}\""));
        let intruder = session("tcp/127.0.0.1:0", &format!("\"tcp/127.0.0.1:{port}\""));
        let mut remote = Remote::subscribe(
            &a,
            "test/owned",
            SpikeChunk::TYPE_URN,
            Duration::from_secs(10),
        )
        .expect("subscribe");
        let declare = |s| matched_publisher(s, "test/owned");
        let (cam, bad) = (declare(&camera), declare(&intruder));
        put(&cam, chunk(0));
        let first = next_taken(&mut remote);
        assert!(matches!(first, Taken::Message(..)), "{first:?}");
        // Another publisher's chunk and its end marker: refused, the stream goes on.
        put(&bad, chunk(1));
        put(&bad, end_of_stream::<SpikeChunk>(2));
        // Two sessions' samples arrive in no set order: let the intruder's be counted first, so
        // that the camera's end marker does not end the stream before them.
        let deadline = Instant::now() + Duration::from_secs(10);
        while remote.foreign() < 2 {
            assert!(
                Instant::now() < deadline,
                "the intruder's samples never arrived"
            );
            let t = remote.next(Duration::from_millis(50)).expect("next");
            assert!(matches!(t, Taken::Idle), "{t:?}");
        }
        put(&cam, chunk(1));
        put(&cam, end_of_stream::<SpikeChunk>(2));
        let mut seqs = Vec::new();
        loop {
            match next_taken(&mut remote) {
                Taken::Message(m, d) => {
                    seqs.push(SpikeChunk::from_arrow(&m, &d).expect("chunk").seq)
                }
                Taken::End { count, .. } => {
                    assert_eq!(count, 2);
                    break;
                }
                Taken::Idle => unreachable!(),
            }
        }
        assert_eq!(seqs, [1]);
        assert_eq!(
            (remote.received(), remote.missing(), remote.foreign()),
            (2, 0, 2)
        );
    }

    #[test]
    fn a_restarted_camera_rejoins_once_the_old_one_is_silent_numbering_afresh() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("port")
            .port();
        let a = session(&format!("tcp/127.0.0.1:{port}"), "");
        let dial = format!("\"tcp/127.0.0.1:{port}\"");
        let rejoin = Duration::from_millis(400);
        let mut remote = Remote::subscribe(
            &a,
            "test/restart",
            SpikeChunk::TYPE_URN,
            Duration::from_secs(10),
        )
        .expect("subscribe")
        .rejoining_after(rejoin);
        let mut seqs = Vec::new();
        let take = |remote: &mut Remote, seqs: &mut Vec<u64>| match next_taken(remote) {
            Taken::Message(m, d) => seqs.push(SpikeChunk::from_arrow(&m, &d).expect("chunk").seq),
            t => panic!("{t:?}"),
        };
        {
            let first = session("tcp/127.0.0.1:0", &dial);
            let cam = matched_publisher(&first, "test/restart");
            for seq in 0..3 {
                put(&cam, chunk(seq));
                take(&mut remote, &mut seqs);
            }
        }
        // The camera restarted as a new process: it numbers from 0 again, and is followed
        // once the old one has been silent for the rejoin time.
        std::thread::sleep(rejoin + Duration::from_millis(100));
        let second = session("tcp/127.0.0.1:0", &dial);
        let cam = matched_publisher(&second, "test/restart");
        put(&cam, chunk(0));
        put(&cam, chunk(1));
        put(&cam, end_of_stream::<SpikeChunk>(2));
        take(&mut remote, &mut seqs);
        take(&mut remote, &mut seqs);
        assert!(matches!(
            next_taken(&mut remote),
            Taken::End { count: 2, .. }
        ));
        assert_eq!(seqs, [0, 1, 2, 0, 1]);
        assert_eq!(
            (
                remote.received(),
                remote.missing(),
                remote.restarts(),
                remote.foreign()
            ),
            (5, 0, 1, 0)
        );
    }

    #[test]
    fn a_silent_key_is_an_error_naming_it() {
        let a = session("tcp/127.0.0.1:0", "");
        let mut remote = Remote::subscribe(
            &a,
            "test/nobody",
            SpikeChunk::TYPE_URN,
            Duration::from_millis(300),
        )
        .expect("subscribe");
        let e = next_error(&mut remote);
        assert!(
            e.starts_with("test/nobody: nothing arrived for 0.3 s"),
            "{e}"
        );
    }
}
