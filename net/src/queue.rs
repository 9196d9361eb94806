//! The queue between zenoh and a node for samples from the network: bounded in samples and in
//! bytes, so that whatever arrives (a flood of large samples included) holds a stated amount of
//! memory. When it is full, zenoh's thread waits for room, so zenoh stops reading the link and a
//! publisher that sends with congestion control `block` is held back instead of losing messages.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

/// Samples a queue holds at most.
pub const QUEUE_SAMPLES: usize = 64;

/// Payload bytes a queue holds at most: 256 MiB, twenty 400 x 250 spike chunks of 1,000 planes.
/// One sample larger than this still passes, alone (the session's largest message bounds it:
/// [`crate::session::MAX_MESSAGE_BYTES`]).
pub const QUEUE_BYTES: usize = 256 << 20;

struct State {
    samples: VecDeque<Sample>,
    bytes: usize,
    closed: bool,
}

struct Shared {
    state: Mutex<State>,
    /// Signalled when a sample comes in, or the queue closes.
    filled: Condvar,
    /// Signalled when a sample goes out, or the queue closes.
    drained: Condvar,
    max_samples: usize,
    max_bytes: usize,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// zenoh's side: waits for room (or the end), then queues the sample.
    fn push(&self, sample: Sample) {
        let len = sample.payload().len();
        let mut s = self.lock();
        while !s.closed
            && !s.samples.is_empty()
            && (s.samples.len() >= self.max_samples || s.bytes + len > self.max_bytes)
        {
            s = self.drained.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        if s.closed {
            return;
        }
        s.bytes += len;
        s.samples.push_back(sample);
        self.filled.notify_one();
    }
}

/// A subscriber whose samples wait in a queue bounded by [`QUEUE_SAMPLES`] and [`QUEUE_BYTES`]
/// (or the bounds given).
pub struct BoundedSubscriber {
    shared: Arc<Shared>,
    _sub: Subscriber<()>,
}

impl BoundedSubscriber {
    /// Subscribes to `key` on `session` with the default bounds.
    ///
    /// # Errors
    /// zenoh refused the subscription.
    pub fn declare(session: &zenoh::Session, key: &str) -> zenoh::Result<Self> {
        Self::with_bounds(session, key, QUEUE_SAMPLES, QUEUE_BYTES)
    }

    /// Subscribes to `key` on `session`; at most `max_samples` samples and `max_bytes` bytes of
    /// payload wait.
    ///
    /// # Errors
    /// zenoh refused the subscription.
    pub fn with_bounds(
        session: &zenoh::Session,
        key: &str,
        max_samples: usize,
        max_bytes: usize,
    ) -> zenoh::Result<Self> {
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                samples: VecDeque::new(),
                bytes: 0,
                closed: false,
            }),
            filled: Condvar::new(),
            drained: Condvar::new(),
            max_samples: max_samples.max(1),
            max_bytes,
        });
        let pushing = Arc::clone(&shared);
        let sub = session
            .declare_subscriber(key.to_string())
            .callback(move |sample| pushing.push(sample))
            .wait()?;
        Ok(BoundedSubscriber { shared, _sub: sub })
    }

    /// The next sample, waiting up to `wait`; `None` when none came.
    pub fn recv_timeout(&self, wait: Duration) -> Option<Sample> {
        let deadline = Instant::now() + wait;
        let mut s = self.shared.lock();
        loop {
            if let Some(sample) = s.samples.pop_front() {
                s.bytes -= sample.payload().len();
                self.shared.drained.notify_all();
                return Some(sample);
            }
            let now = Instant::now();
            if now >= deadline {
                return None;
            }
            s = self
                .shared
                .filled
                .wait_timeout(s, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// Samples and payload bytes waiting now.
    pub fn held(&self) -> (usize, usize) {
        let s = self.shared.lock();
        (s.samples.len(), s.bytes)
    }
}

impl Drop for BoundedSubscriber {
    fn drop(&mut self) {
        // zenoh's thread may be waiting for room: let it go, dropping what it holds.
        let mut s = self.shared.lock();
        s.closed = true;
        s.samples.clear();
        self.shared.drained.notify_all();
        self.shared.filled.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session() -> zenoh::Session {
        let mut c = zenoh::Config::default();
        c.insert_json5("mode", "\"peer\"").expect("mode");
        c.insert_json5("listen/endpoints", "[]").expect("listen");
        c.insert_json5("scouting/multicast/enabled", "false")
            .expect("scouting");
        zenoh::open(c).wait().expect("session")
    }

    #[test]
    fn the_queue_holds_at_most_its_bytes_and_hands_every_sample_on_in_order() {
        let s = session();
        let sub = BoundedSubscriber::with_bounds(&s, "test/bytes", 64, 10_000).expect("sub");
        let publisher = s.declare_publisher("test/bytes").wait().expect("publisher");
        // Forty samples of 1,000 bytes from another thread: at most ten wait at a time.
        let sender = std::thread::spawn(move || {
            for i in 0..40u8 {
                publisher.put(vec![i; 1_000]).wait().expect("put");
            }
        });
        let mut got = Vec::new();
        let mut most = 0;
        while got.len() < 40 {
            std::thread::sleep(Duration::from_millis(2));
            most = most.max(sub.held().1);
            if let Some(sample) = sub.recv_timeout(Duration::from_secs(10)) {
                got.push(sample.payload().to_bytes()[0]);
            } else {
                panic!("a sample never came ({} so far)", got.len());
            }
        }
        sender.join().expect("sender");
        assert_eq!(got, (0..40).collect::<Vec<u8>>());
        assert!(most <= 10_000, "{most} bytes waited");
        assert!(sub.recv_timeout(Duration::from_millis(10)).is_none());
    }
}
