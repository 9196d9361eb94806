//! A source's pace: as fast as its consumers take its messages, or on the camera's clock.

use std::time::{Duration, Instant};

/// Now, Unix nanoseconds (0 before 1970, saturated after 2262).
pub fn unix_now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

/// How fast a source sends its messages.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Pace {
    /// As fast as the receivers take them.
    #[default]
    Fast,
    /// On the camera's clock: a message leaves when the camera time it covers has passed.
    Realtime,
}

/// Holds a source's messages back to the camera's clock under [`Pace::Realtime`].
#[derive(Clone, Copy, Debug)]
pub struct Pacer {
    pace: Pace,
    start: Instant,
    start_unix_ns: i64,
}

impl Pacer {
    /// A clock starting now.
    pub fn start(pace: Pace) -> Self {
        Pacer {
            pace,
            start: Instant::now(),
            start_unix_ns: unix_now_ns(),
        }
    }

    /// A clock that started at `start_unix_ns` (ns since the epoch; a later time counts as now):
    /// a restarted source's, on its first start's clock.
    pub fn started_at(pace: Pace, start_unix_ns: i64) -> Self {
        let now = Instant::now();
        let now_unix = unix_now_ns();
        let ago = u64::try_from(now_unix.saturating_sub(start_unix_ns)).unwrap_or(0);
        let start = now.checked_sub(Duration::from_nanos(ago)).unwrap_or(now);
        Pacer {
            pace,
            start,
            start_unix_ns: start_unix_ns.min(now_unix),
        }
    }

    /// The pace it keeps.
    pub fn pace(&self) -> Pace {
        self.pace
    }

    /// Camera time since the clock's start, ns (0 when not paced: a fast source has no clock).
    pub fn elapsed_ns(&self) -> i64 {
        match self.pace {
            Pace::Realtime => i64::try_from(self.start.elapsed().as_nanos()).unwrap_or(i64::MAX),
            Pace::Fast => 0,
        }
    }

    /// Waits until `stream_ns` of camera time have passed since the start (no wait when fast;
    /// a negative time is due at once). Under [`Pace::Realtime`], returns the wall time (ns since
    /// the epoch) at which a camera would have delivered that data: a source that has fallen
    /// behind stamps it as its messages' origin ([`crate::Outbox::set_origin`]), so their latency
    /// counts the time they waited, as a real camera's buffer would hold them.
    pub fn wait_until(&self, stream_ns: i64) -> Option<i64> {
        if self.pace != Pace::Realtime {
            return None;
        }
        let stream_ns = stream_ns.max(0);
        let due = self.start + Duration::from_nanos(stream_ns as u64);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        Some(self.start_unix_ns.saturating_add(stream_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_paced_source_learns_when_the_camera_would_have_delivered_its_data() {
        assert_eq!(Pacer::start(Pace::Fast).wait_until(1_000_000_000), None);
        let before = unix_now_ns();
        let p = Pacer::start(Pace::Realtime);
        let start = Instant::now();
        // Due 2 ms after the start: waited for, and stamped 2 ms after the start.
        let due = p.wait_until(2_000_000).expect("paced");
        assert!(start.elapsed() >= Duration::from_millis(2));
        assert!(due >= before + 2_000_000 && due <= unix_now_ns(), "{due}");
        // Past data is due at once, stamped when it was due (a negative time at the start).
        let t = Instant::now();
        assert_eq!(p.wait_until(1_000_000), Some(due - 1_000_000));
        assert_eq!(p.wait_until(-5), Some(due - 2_000_000));
        assert!(t.elapsed() < Duration::from_millis(50));
        // A restarted source's clock runs from its first start.
        let earlier = Pacer::started_at(Pace::Realtime, unix_now_ns() - 3_000_000_000);
        let e = earlier.elapsed_ns();
        assert!((3_000_000_000..3_100_000_000).contains(&e), "{e}");
        assert_eq!(Pacer::started_at(Pace::Fast, 0).elapsed_ns(), 0);
    }
}
