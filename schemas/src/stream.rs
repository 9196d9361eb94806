//! Sequence numbers and end-of-stream markers: how a receiver knows nothing went missing.

use arrow::array::{ArrayRef, new_empty_array};

use crate::Message;
use crate::meta::{self, Meta, MetaExt, Parameter};

/// The end-of-stream marker of an output that sent `count` messages (sequence numbers
/// `0..count`): an empty payload of the stream's type, `eos = true`, `count`.
pub fn end_of_stream<M: Message>(count: u64) -> (Meta, ArrayRef) {
    (
        end_of_stream_header(count),
        new_empty_array(&M::data_type()),
    )
}

/// The header of an end-of-stream marker after `count` messages (a count beyond `i64::MAX`
/// saturates).
pub fn end_of_stream_header(count: u64) -> Meta {
    let mut m = Meta::new();
    m.insert(meta::EOS.to_string(), Parameter::Bool(true));
    m.set_int(meta::COUNT, i64::try_from(count).unwrap_or(i64::MAX));
    m
}

/// `Some(count)` when the message is an end-of-stream marker.
pub fn is_end_of_stream(m: &Meta) -> Option<u64> {
    if !m.flag(meta::EOS) {
        return None;
    }
    match m.get(meta::COUNT) {
        Some(Parameter::Integer(c)) if *c >= 0 => Some(*c as u64),
        _ => Some(0),
    }
}

/// What a received sequence number says about the stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqStatus {
    /// The next expected message.
    InOrder,
    /// `missing` messages were skipped before this one.
    Gap {
        /// How many sequence numbers were skipped.
        missing: u64,
    },
    /// A message at or before one already seen (duplicate or reordered).
    Stale,
    /// A number more than [`MAX_SEQ_JUMP`] past the next expected one: refused and counted, the
    /// expected number unchanged (a forged or corrupt number must not make the genuine
    /// messages after it look stale, nor count billions lost).
    Anomaly {
        /// How far past the next expected number it was.
        jump: u64,
    },
    /// The [`RESYNC_AFTER`]th message in a row continuing one jump past [`MAX_SEQ_JUMP`]: the
    /// sender renumbered its stream (it restarted), and the tracker follows it from here. The
    /// numbers skipped count neither as lost nor as received.
    Resynced {
        /// How far past the previously expected number the stream resumed.
        jump: u64,
    },
    /// The first number from a new sender ([`SeqTracker::rejoin`]) behind the stream's: the
    /// sender restarted and numbers afresh. The tracker follows it from here; what the sender
    /// lost while it was down cannot be told from the numbers, and is counted as one restart.
    Restarted {
        /// The number the stream expected.
        expected: u64,
    },
}

/// How far past the next expected sequence number a message may be and still be taken, the
/// numbers skipped counted as lost: 65,536 messages (over a minute of loss at 1,000 messages a
/// second). A larger jump is a [`SeqStatus::Anomaly`].
pub const MAX_SEQ_JUMP: u64 = 1 << 16;

/// Messages in a row, each one past the last and all beyond [`MAX_SEQ_JUMP`], after which the
/// stream is taken to have been renumbered ([`SeqStatus::Resynced`]).
pub const RESYNC_AFTER: u64 = 4;

/// Follows the sequence numbers of one input and counts what went missing.
#[derive(Clone, Debug, Default)]
pub struct SeqTracker {
    next: u64,
    received: u64,
    missing: u64,
    stale: u64,
    anomalies: u64,
    resyncs: u64,
    /// A run of anomalies each one past the last: the number it expects next, and its length.
    run: Option<(u64, u64)>,
    announced: Option<u64>,
    /// The next number comes from a new sender ([`Self::rejoin`]).
    rejoining: bool,
    restarts: u64,
}

impl SeqTracker {
    /// Records a received sequence number.
    pub fn observe(&mut self, seq: u64) -> SeqStatus {
        if std::mem::take(&mut self.rejoining) && seq < self.next {
            let expected = self.next;
            self.run = None;
            self.restarts += 1;
            self.received += 1;
            self.next = seq.saturating_add(1);
            return SeqStatus::Restarted { expected };
        }
        if seq < self.next {
            self.stale += 1;
            return SeqStatus::Stale;
        }
        let jump = seq - self.next;
        if jump > MAX_SEQ_JUMP {
            let run = match self.run {
                Some((expect, n)) if expect == seq => n + 1,
                _ => 1,
            };
            if run < RESYNC_AFTER {
                self.anomalies += 1;
                self.run = Some((seq.saturating_add(1), run));
                return SeqStatus::Anomaly { jump };
            }
            // The run's earlier messages were refused: they stay counted as anomalies.
            self.run = None;
            self.resyncs += 1;
            self.received += 1;
            self.next = seq.saturating_add(1);
            return SeqStatus::Resynced { jump };
        }
        self.run = None;
        self.received += 1;
        let status = if jump == 0 {
            SeqStatus::InOrder
        } else {
            self.missing += jump;
            SeqStatus::Gap { missing: jump }
        };
        self.next = seq.saturating_add(1);
        status
    }

    /// Records the end-of-stream marker; returns how many messages were lost at the tail. A
    /// count more than [`MAX_SEQ_JUMP`] past the messages seen is an anomaly: the stream ends
    /// at what came, nothing counted lost at its tail.
    pub fn end(&mut self, count: u64) -> u64 {
        if count.saturating_sub(self.next) > MAX_SEQ_JUMP {
            self.anomalies += 1;
            self.announced = Some(self.next);
            return 0;
        }
        self.announced = Some(count);
        let tail = count.saturating_sub(self.next);
        self.missing += tail;
        self.next = self.next.max(count);
        tail
    }

    /// Messages refused for a sequence number too far ahead ([`SeqStatus::Anomaly`]), and end
    /// markers announcing too many.
    pub fn anomalies(&self) -> u64 {
        self.anomalies
    }

    /// The stream's sender changed (a camera restarted as a new process): its next number
    /// may start afresh. One behind the stream's is followed ([`SeqStatus::Restarted`]); one at
    /// or past it is taken as any other (a gap counted as lost, a jump too far refused).
    pub fn rejoin(&mut self) {
        self.rejoining = true;
    }

    /// Times a new sender numbered afresh ([`SeqStatus::Restarted`]).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Times the stream was renumbered ([`SeqStatus::Resynced`]).
    pub fn resyncs(&self) -> u64 {
        self.resyncs
    }

    /// Messages received (excluding stale ones).
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Messages known to be missing so far.
    pub fn missing(&self) -> u64 {
        self.missing
    }

    /// Stale (duplicate or reordered) messages ignored.
    pub fn stale(&self) -> u64 {
        self.stale
    }

    /// The count announced by the end-of-stream marker, if it arrived.
    pub fn announced(&self) -> Option<u64> {
        self.announced
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Frame;

    #[test]
    fn tracker_counts_gaps_and_tail() {
        let mut t = SeqTracker::default();
        assert_eq!(t.observe(0), SeqStatus::InOrder);
        assert_eq!(t.observe(3), SeqStatus::Gap { missing: 2 });
        assert_eq!(t.observe(3), SeqStatus::Stale);
        assert_eq!(t.end(6), 2);
        assert_eq!(
            (t.received(), t.missing(), t.stale(), t.announced()),
            (2, 4, 1, Some(6))
        );
    }

    #[test]
    fn a_new_sender_numbering_afresh_is_followed_and_one_continuing_has_its_gap_counted() {
        let mut t = SeqTracker::default();
        for seq in 0..10 {
            t.observe(seq);
        }
        // Without a rejoin, numbers from behind are stale.
        assert_eq!(t.observe(0), SeqStatus::Stale);
        t.rejoin();
        assert_eq!(t.observe(0), SeqStatus::Restarted { expected: 10 });
        assert_eq!(t.observe(1), SeqStatus::InOrder);
        assert_eq!((t.received(), t.missing(), t.restarts()), (12, 0, 1));
        // A restarted sender that numbers as if it had sent everything: its gap is lost.
        t.rejoin();
        assert_eq!(t.observe(7), SeqStatus::Gap { missing: 5 });
        assert_eq!((t.missing(), t.restarts()), (5, 1));
        // The rejoin holds for one number only.
        assert_eq!(t.observe(3), SeqStatus::Stale);
    }

    #[test]
    fn a_forged_jump_is_refused_without_blinding_the_stream() {
        let mut t = SeqTracker::default();
        assert_eq!(t.observe(0), SeqStatus::InOrder);
        assert_eq!(
            t.observe(1 << 62),
            SeqStatus::Anomaly {
                jump: (1 << 62) - 1
            }
        );
        // The genuine messages after it are in order, nothing counted lost.
        assert_eq!(t.observe(1), SeqStatus::InOrder);
        assert_eq!(t.observe(2), SeqStatus::InOrder);
        assert_eq!((t.received(), t.missing(), t.anomalies()), (3, 0, 1));
        // A jump within the window is loss, as before.
        assert_eq!(
            t.observe(3 + MAX_SEQ_JUMP),
            SeqStatus::Gap {
                missing: MAX_SEQ_JUMP
            }
        );
        // A forged end marker far ahead ends the stream at what came, with no tail lost.
        assert_eq!(t.end(u64::MAX), 0);
        assert_eq!(t.announced(), Some(4 + MAX_SEQ_JUMP));
        assert_eq!(t.anomalies(), 2);
    }

    #[test]
    fn a_renumbered_stream_is_followed_after_a_run_of_consecutive_numbers() {
        let mut t = SeqTracker::default();
        for s in 0..10 {
            assert_eq!(t.observe(s), SeqStatus::InOrder);
        }
        let base = 1_000_000;
        for k in 0..RESYNC_AFTER - 1 {
            assert!(matches!(t.observe(base + k), SeqStatus::Anomaly { .. }));
        }
        assert_eq!(
            t.observe(base + RESYNC_AFTER - 1),
            SeqStatus::Resynced {
                jump: base + RESYNC_AFTER - 1 - 10
            }
        );
        assert_eq!(t.observe(base + RESYNC_AFTER), SeqStatus::InOrder);
        assert_eq!(t.observe(5), SeqStatus::Stale);
        assert_eq!(
            (t.missing(), t.resyncs(), t.anomalies()),
            (0, 1, RESYNC_AFTER - 1)
        );
        // A run broken by a genuine message starts again.
        let mut u = SeqTracker::default();
        assert!(matches!(u.observe(1 << 40), SeqStatus::Anomaly { .. }));
        assert_eq!(u.observe(0), SeqStatus::InOrder);
        assert!(matches!(
            u.observe((1 << 40) + 1),
            SeqStatus::Anomaly { .. }
        ));
        assert!(matches!(
            u.observe((1 << 40) + 2),
            SeqStatus::Anomaly { .. }
        ));
        assert!(matches!(
            u.observe((1 << 40) + 3),
            SeqStatus::Anomaly { .. }
        ));
    }

    #[test]
    fn eos_marker() {
        let (m, a) = end_of_stream::<Frame>(12);
        assert_eq!(is_end_of_stream(&m), Some(12));
        assert_eq!(a.len(), 0);
        assert_eq!(is_end_of_stream(&Meta::new()), None);
    }
}
