//! Puts one input's messages back in sequence order.
//!
//! dora 1.1 sends a large message through zero-copy shared memory, or through the daemon when the
//! sender's shared-memory pool is momentarily full; the two paths take different times, so the
//! messages of one output can arrive out of order. A [`Reorder`] holds a message that comes
//! before its turn until the ones before it arrive, and gives up on a missing one (a loss, then
//! counted as a gap) after a wait or once it holds too many.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

/// How long a message waits for the ones before it before they count as lost.
pub const MAX_WAIT: Duration = Duration::from_millis(500);
/// How many messages of one input are held at most before the missing ones count as lost.
pub const MAX_HELD: usize = 256;

/// What [`Reorder::push`] did with a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    /// Held until its turn (perhaps at once: see [`Reorder::pop`]).
    Held,
    /// Its turn had passed (a duplicate, or a message already given up on): dropped.
    Late,
}

/// One input's messages, by position: a message's sequence number, or for its end-of-stream
/// marker the count it announces.
#[derive(Debug)]
pub struct Reorder<T> {
    next: u64,
    held: BTreeMap<u64, (T, Instant)>,
    /// Messages due at once, before anything held: a restarted sender's predecessor's.
    ready: VecDeque<(u64, T)>,
    max_wait: Duration,
    max_held: usize,
}

impl<T> Default for Reorder<T> {
    fn default() -> Self {
        Self::new(MAX_WAIT, MAX_HELD)
    }
}

impl<T> Reorder<T> {
    /// An empty buffer expecting position 0.
    pub fn new(max_wait: Duration, max_held: usize) -> Self {
        Reorder {
            next: 0,
            held: BTreeMap::new(),
            ready: VecDeque::new(),
            max_wait,
            max_held: max_held.max(1),
        }
    }

    /// Takes the message at `pos`, arrived at `now`.
    pub fn push(&mut self, pos: u64, item: T, now: Instant) -> Pushed {
        if pos < self.next || self.held.contains_key(&pos) {
            return Pushed::Late;
        }
        self.held.insert(pos, (item, now));
        Pushed::Held
    }

    /// The next message in order, if its turn has come: it is the next position, or the
    /// messages before it waited too long or too many are held (they count as lost).
    pub fn pop(&mut self, now: Instant) -> Option<(u64, T)> {
        if let Some(first) = self.ready.pop_front() {
            return Some(first);
        }
        let (&pos, (_, since)) = self.held.first_key_value()?;
        let due = pos == self.next
            || now.saturating_duration_since(*since) >= self.max_wait
            || self.held.len() > self.max_held;
        if !due {
            return None;
        }
        let (pos, (item, _)) = self.held.pop_first()?;
        self.next = pos.saturating_add(1);
        Some((pos, item))
    }

    /// Everything held, in order (the stream ended: nothing more will come).
    pub fn pop_any(&mut self) -> Option<(u64, T)> {
        if let Some(first) = self.ready.pop_front() {
            return Some(first);
        }
        let (pos, (item, _)) = self.held.pop_first()?;
        self.next = pos.saturating_add(1);
        Some((pos, item))
    }

    /// The sender restarted and numbers its messages from 0 again: what is held is due at once,
    /// in order, and the new numbering starts.
    pub fn restart(&mut self) {
        while let Some((pos, (item, _))) = self.held.pop_first() {
            self.ready.push_back((pos, item));
        }
        self.next = 0;
    }

    /// When the first held message stops waiting, if one waits.
    pub fn deadline(&self) -> Option<Instant> {
        self.held
            .first_key_value()
            .map(|(_, (_, since))| *since + self.max_wait)
    }

    /// Messages held.
    pub fn len(&self) -> usize {
        self.held.len() + self.ready.len()
    }

    /// Whether nothing is held.
    pub fn is_empty(&self) -> bool {
        self.held.is_empty() && self.ready.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_come_out_in_order_and_a_late_one_is_dropped() {
        let t0 = Instant::now();
        let mut r = Reorder::new(Duration::from_millis(10), 8);
        assert_eq!(r.push(2, "c", t0), Pushed::Held);
        assert_eq!(r.push(0, "a", t0), Pushed::Held);
        assert_eq!(r.pop(t0), Some((0, "a")));
        assert_eq!(r.pop(t0), None, "1 has not come");
        assert_eq!(r.deadline(), Some(t0 + Duration::from_millis(10)));
        assert_eq!(r.push(1, "b", t0), Pushed::Held);
        assert_eq!(r.pop(t0), Some((1, "b")));
        assert_eq!(r.pop(t0), Some((2, "c")));
        assert!(r.is_empty());
        assert_eq!(r.push(1, "again", t0), Pushed::Late);
    }

    #[test]
    fn a_missing_message_is_given_up_after_the_wait_or_when_too_many_wait() {
        let t0 = Instant::now();
        let mut r = Reorder::new(Duration::from_millis(10), 2);
        r.push(1, 'b', t0);
        assert_eq!(r.pop(t0 + Duration::from_millis(9)), None);
        assert_eq!(r.pop(t0 + Duration::from_millis(10)), Some((1, 'b')));
        // 2 missing; 3, 4 and 5 held: more than 2 wait, so 3 goes.
        for (p, c) in [(3, 'd'), (4, 'e')] {
            r.push(p, c, t0);
        }
        assert_eq!(r.pop(t0), None);
        r.push(5, 'f', t0);
        assert_eq!(r.pop(t0), Some((3, 'd')));
        assert_eq!(r.pop(t0), Some((4, 'e')));
        assert_eq!(r.pop(t0), Some((5, 'f')));
        // The one given up on is late when it comes.
        assert_eq!(r.push(2, 'c', t0), Pushed::Late);
        r.push(9, 'j', t0);
        assert_eq!(r.pop_any(), Some((9, 'j')));
        assert_eq!(r.len(), 0);
    }

    #[test]
    fn after_a_restart_what_is_held_goes_first_and_numbering_starts_again() {
        let t0 = Instant::now();
        let mut r = Reorder::new(Duration::from_secs(10), 8);
        r.push(0, "a", t0);
        assert_eq!(r.pop(t0), Some((0, "a")));
        r.push(2, "c", t0); // waits for 1, which the dead sender never sent
        assert_eq!(r.pop(t0), None);
        r.restart();
        assert_eq!(r.push(0, "new-0", t0), Pushed::Held);
        assert_eq!(r.len(), 2);
        assert_eq!(r.pop(t0), Some((2, "c")));
        assert_eq!(r.pop(t0), Some((0, "new-0")));
        assert!(r.is_empty());
    }
}
