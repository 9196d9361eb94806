//! Test helpers shared by the kernels' test modules: owned events and random event strategies.

use proptest::prelude::*;

use crate::EventSlice;

/// Owned events for tests; [`Events::slice`] borrows them as the kernels take them.
#[derive(Clone, Debug, Default)]
pub(crate) struct Events {
    pub t_ns: Vec<i64>,
    pub x: Vec<u16>,
    pub y: Vec<u16>,
    pub polarity: Vec<i8>,
}

impl Events {
    /// Events from `(t_ns, x, y, polarity)` tuples, kept in the order given.
    pub fn from(list: &[(i64, u16, u16, i8)]) -> Self {
        let mut e = Self::default();
        for &(t, x, y, p) in list {
            e.push(t, x, y, p);
        }
        e
    }

    pub fn push(&mut self, t_ns: i64, x: u16, y: u16, polarity: i8) {
        self.t_ns.push(t_ns);
        self.x.push(x);
        self.y.push(y);
        self.polarity.push(polarity);
    }

    pub fn slice(&self) -> EventSlice<'_> {
        EventSlice {
            t_ns: &self.t_ns,
            x: &self.x,
            y: &self.y,
            polarity: &self.polarity,
        }
    }

    /// `n` events on an `h x w` sensor from a fixed-seed generator (xorshift), times sorted over
    /// `t0_ns + [0, span_ns]` (the first at `t0_ns`, the last at `t0_ns + span_ns` when `n >= 2`),
    /// about a third OFF. Deterministic: the same arguments give the same events.
    pub fn flood(n: usize, h: usize, w: usize, t0_ns: i64, span_ns: i64, seed: u64) -> Self {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let mut e = Self {
            t_ns: Vec::with_capacity(n),
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            polarity: Vec::with_capacity(n),
        };
        let last = n.saturating_sub(1).max(1) as i128;
        for i in 0..n {
            let r = next();
            let t = i128::from(t0_ns) + i128::from(span_ns) * i as i128 / last;
            e.push(
                t as i64,
                ((r >> 8) % w as u64) as u16,
                ((r >> 24) % h as u64) as u16,
                if (r >> 40).is_multiple_of(3) { -1 } else { 1 },
            );
        }
        e
    }

    /// Signed count at each pixel, `[h * w]` row-major, in `i64`.
    pub fn signed_counts(&self, h: usize, w: usize) -> Vec<i64> {
        let mut c = vec![0i64; h * w];
        for i in 0..self.t_ns.len() {
            c[usize::from(self.y[i]) * w + usize::from(self.x[i])] += i64::from(self.polarity[i]);
        }
        c
    }
}

/// Random sorted events on a random small sensor: `(events, h, w)`, `h` in `1..h_max`, `w` in
/// `1..w_max`, up to `n_max - 1` events with times drawn from `times` (many ties when the range
/// is narrow).
pub(crate) fn sorted_events(
    h_max: usize,
    w_max: usize,
    n_max: usize,
    times: impl Strategy<Value = i64> + Clone + 'static,
) -> impl Strategy<Value = (Events, usize, usize)> {
    (1..h_max, 1..w_max, 0..n_max).prop_flat_map(move |(h, w, n)| {
        let event = (
            times.clone(),
            0..w as u16,
            0..h as u16,
            prop_oneof![Just(1i8), Just(-1i8)],
        );
        proptest::collection::vec(event, n).prop_map(move |mut list| {
            list.sort_by_key(|e| e.0);
            (Events::from(&list), h, w)
        })
    })
}

/// Random sorted events in one of four time regimes chosen per case: a narrow range (many ties),
/// a millisecond range, the whole `i64` range, and the top of it (next to `i64::MAX`).
pub(crate) fn any_events(
    h_max: usize,
    w_max: usize,
    n_max: usize,
) -> impl Strategy<Value = (Events, usize, usize)> {
    prop_oneof![
        sorted_events(h_max, w_max, n_max, 0i64..4),
        sorted_events(h_max, w_max, n_max, -1_000i64..1_000_000),
        sorted_events(h_max, w_max, n_max, any::<i64>()),
        sorted_events(h_max, w_max, n_max, (i64::MAX - 1_000)..=i64::MAX),
    ]
}
