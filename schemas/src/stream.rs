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
}

/// Follows the sequence numbers of one input and counts what went missing.
#[derive(Clone, Debug, Default)]
pub struct SeqTracker {
    next: u64,
    received: u64,
    missing: u64,
    stale: u64,
    announced: Option<u64>,
}

impl SeqTracker {
    /// Records a received sequence number.
    pub fn observe(&mut self, seq: u64) -> SeqStatus {
        if seq < self.next {
            self.stale += 1;
            return SeqStatus::Stale;
        }
        self.received += 1;
        let status = if seq == self.next {
            SeqStatus::InOrder
        } else {
            let missing = seq - self.next;
            self.missing += missing;
            SeqStatus::Gap { missing }
        };
        self.next = seq + 1;
        status
    }

    /// Records the end-of-stream marker; returns how many messages were lost at the tail.
    pub fn end(&mut self, count: u64) -> u64 {
        self.announced = Some(count);
        let tail = count.saturating_sub(self.next);
        self.missing += tail;
        self.next = self.next.max(count);
        tail
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
    fn eos_marker() {
        let (m, a) = end_of_stream::<Frame>(12);
        assert_eq!(is_end_of_stream(&m), Some(12));
        assert_eq!(a.len(), 0);
        assert_eq!(is_end_of_stream(&Meta::new()), None);
    }
}
