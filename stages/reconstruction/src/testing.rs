//! Test helpers: owned events and random event streams.

use neuspike_representations::EventSlice;
use proptest::prelude::*;

/// Owned events, the columns of an [`EventSlice`].
#[derive(Clone, Debug, Default)]
pub(crate) struct EventBuf {
    pub t_ns: Vec<i64>,
    pub x: Vec<u16>,
    pub y: Vec<u16>,
    pub polarity: Vec<i8>,
}

impl EventBuf {
    /// Events from `(t_ns, x, y, polarity)` tuples, as given (unsorted allowed, for error tests).
    pub fn from(list: &[(i64, u16, u16, i8)]) -> Self {
        let mut b = EventBuf::default();
        for &(t, x, y, p) in list {
            b.push(t, x, y, p);
        }
        b
    }

    pub fn push(&mut self, t_ns: i64, x: u16, y: u16, polarity: i8) {
        self.t_ns.push(t_ns);
        self.x.push(x);
        self.y.push(y);
        self.polarity.push(polarity);
    }

    pub fn len(&self) -> usize {
        self.t_ns.len()
    }

    pub fn slice(&self) -> EventSlice<'_> {
        self.range(0, self.len())
    }

    /// Events `a..b`.
    pub fn range(&self, a: usize, b: usize) -> EventSlice<'_> {
        EventSlice {
            t_ns: &self.t_ns[a..b],
            x: &self.x[a..b],
            y: &self.y[a..b],
            polarity: &self.polarity[a..b],
        }
    }
}

/// A sensor of 1..=`max_side` rows and columns with up to `max_events` events after `t0_ns`,
/// time steps of 0 to `max_step_ns` (repeats included), cut into pushes at sorted `cuts`.
pub(crate) fn stream(
    max_side: usize,
    max_events: usize,
    max_step_ns: i64,
) -> impl Strategy<Value = (usize, usize, EventBuf, Vec<usize>)> {
    (1..=max_side, 1..=max_side).prop_flat_map(move |(h, w)| {
        let event = (0..=max_step_ns, 0..w as u16, 0..h as u16, any::<bool>());
        (
            Just(h),
            Just(w),
            proptest::collection::vec(event, 0..=max_events),
            proptest::collection::vec(0..=max_events, 0..4),
        )
            .prop_map(|(h, w, raw, mut cuts)| {
                let mut b = EventBuf::default();
                let mut t = 0i64;
                for (dt, x, y, on) in raw {
                    t += dt;
                    b.push(t, x, y, if on { 1 } else { -1 });
                }
                cuts.iter_mut().for_each(|c| *c = (*c).min(b.len()));
                cuts.push(b.len());
                cuts.sort_unstable();
                (h, w, b, cuts)
            })
    })
}

/// Whether `a` and `b` agree to `rel` relative (and `rel` absolute near 0).
pub(crate) fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * (1.0 + b.abs())
}
