//! Aligned windows: the spike planes and the events that belong to one reconstruction instant.

use std::sync::Arc;

use arrow::array::{Array, ArrayRef, LargeBinaryArray, LargeListArray, StructArray};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::{DataType, Field, Fields};

use crate::Message;
use crate::events::EventBatch;
use crate::meta::{self, Meta, MetaExt, SchemaError, check_type, int_of};
use crate::spikes::{SpikeChunk, bytes_per_plane};

const NAME: &str = "aligned window";

/// The spike planes and events around one reconstruction instant, on the spike clock.
///
/// `spikes` holds the window's planes (its `seq` is the window's); `ref_plane` is the global index
/// of the plane at `t_ref_ns`; `events` holds the events of `[events.t_start_ns, events.t_end_ns)`
/// with timestamps already shifted onto the spike clock.
#[derive(Clone, Debug, PartialEq)]
pub struct AlignedWindow {
    /// The reconstruction instant, nanoseconds.
    pub t_ref_ns: i64,
    /// Global index of the reference plane (inside the window's planes).
    pub ref_plane: u64,
    /// The window's spike planes.
    pub spikes: SpikeChunk,
    /// The window's events (may be empty, and has size 0x0 when the graph has no event camera).
    pub events: EventBatch,
}

/// Where a window of fewer planes around the same reference plane lies inside a window
/// ([`AlignedWindow::central`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Central {
    /// Its first plane, as an index into the window's planes.
    pub first: usize,
    /// The start of its events' span, nanoseconds (one plane period before its first plane).
    pub t_start_ns: i64,
    /// The end (exclusive) of its events' span: its last plane's time, nanoseconds.
    pub t_end_ns: i64,
    /// Its events, as indices into the window's events.
    pub events: std::ops::Range<usize>,
}

impl AlignedWindow {
    /// Sequence number of the window.
    pub fn seq(&self) -> u64 {
        self.spikes.seq
    }

    /// Index of the reference plane inside the window's planes.
    pub fn ref_index(&self) -> usize {
        (self.ref_plane - self.spikes.first_plane) as usize
    }

    /// The window of `n` planes around the same reference plane, as align cuts a window of `n`
    /// planes (`ref - n/2 ..= ref + n - 1 - n/2`, the events of `[t_first - T, t_last)`); `None`
    /// when this window does not hold those planes (or `n` is 0).
    pub fn crop(&self, n: usize) -> Option<AlignedWindow> {
        let span = self.central(n)?;
        let ev = &self.events;
        let r = span.events;
        let mut out = self.crop_spikes(n)?;
        out.events.t_ns = ev.t_ns[r.clone()].to_vec();
        out.events.x = ev.x[r.clone()].to_vec();
        out.events.y = ev.y[r.clone()].to_vec();
        out.events.polarity = ev.polarity[r].to_vec();
        Some(out)
    }

    /// [`Self::crop`] without the events: the same planes, and an event batch of the same span
    /// and size that holds none. For what reads spikes alone: copying the events of a busy
    /// window costs more than the spikes (a million events are 12 MB).
    pub fn crop_spikes(&self, n: usize) -> Option<AlignedWindow> {
        let span = self.central(n)?;
        let s = &self.spikes;
        let per = bytes_per_plane(s.width, s.height);
        let first = span.first;
        let bits = s.bits.get(first * per..(first + n) * per)?.to_vec();
        let ev = &self.events;
        Some(AlignedWindow {
            t_ref_ns: self.t_ref_ns,
            ref_plane: self.ref_plane,
            spikes: SpikeChunk {
                first_plane: s.first_plane + first as u64,
                n_planes: n,
                t_first_ns: s.plane_time_ns(first),
                bits,
                ..s.header_only()
            },
            events: EventBatch::empty(
                ev.width,
                ev.height,
                span.t_start_ns.max(ev.t_start_ns),
                span.t_end_ns.min(ev.t_end_ns),
                ev.seq,
            ),
        })
    }

    /// The part of the window over the rectangle `x0..x0 + width`, `y0..y0 + height` of the
    /// spike grid, every plane: the spikes repacked at that size, and (with `events`) the events
    /// that fall in it, shifted by `(-x0, -y0)` (without, an empty batch of the same span). The
    /// event batch takes the rectangle's size when the window has events of the grid's size (0x0
    /// stays 0x0). `None` when the rectangle is empty or does not lie in the grid.
    pub fn region(
        &self,
        x0: usize,
        y0: usize,
        width: usize,
        height: usize,
        events: bool,
    ) -> Option<AlignedWindow> {
        let s = &self.spikes;
        if width == 0
            || height == 0
            || x0.checked_add(width)? > s.width
            || y0.checked_add(height)? > s.height
        {
            return None;
        }
        let per = bytes_per_plane(s.width, s.height);
        let per_out = bytes_per_plane(width, height);
        if s.bits.len() < s.n_planes * per {
            return None;
        }
        let mut bits = vec![0u8; s.n_planes * per_out];
        for p in 0..s.n_planes {
            let src = &s.bits[p * per..(p + 1) * per];
            let dst = &mut bits[p * per_out..(p + 1) * per_out];
            for y in 0..height {
                copy_bits(src, (y0 + y) * s.width + x0, dst, y * width, width);
            }
        }
        let ev = &self.events;
        let sized = |n: usize| if ev.width == 0 { 0 } else { n };
        let mut out_ev = EventBatch::empty(
            sized(width),
            sized(height),
            ev.t_start_ns,
            ev.t_end_ns,
            ev.seq,
        );
        if events {
            let (xr, yr) = (x0..x0 + width, y0..y0 + height);
            for i in 0..ev.t_ns.len() {
                let (x, y) = (usize::from(ev.x[i]), usize::from(ev.y[i]));
                if xr.contains(&x) && yr.contains(&y) {
                    out_ev.t_ns.push(ev.t_ns[i]);
                    // Inside a rectangle of the grid: below the grid's size, which fits in u16
                    // as the events' own coordinates did.
                    out_ev.x.push((x - x0) as u16);
                    out_ev.y.push((y - y0) as u16);
                    out_ev.polarity.push(ev.polarity[i]);
                }
            }
        }
        Some(AlignedWindow {
            t_ref_ns: self.t_ref_ns,
            ref_plane: self.ref_plane,
            spikes: SpikeChunk {
                width,
                height,
                bits,
                ..s.header_only()
            },
            events: out_ev,
        })
    }

    /// Where [`Self::crop`]'s window of `n` planes lies in this one, without copying anything;
    /// `None` when this window does not hold those planes (or `n` is 0).
    pub fn central(&self, n: usize) -> Option<Central> {
        let s = &self.spikes;
        let c = self.ref_index();
        if n == 0 || c < n / 2 || c + (n - 1 - n / 2) >= s.n_planes {
            return None;
        }
        let first = c - n / 2;
        let t_start_ns = s.plane_time_ns(first).saturating_sub(s.plane_period_ns);
        let t_end_ns = s.plane_time_ns(first + n - 1);
        let ev = &self.events.t_ns;
        let lo = ev.partition_point(|&t| t < t_start_ns);
        let hi = ev.partition_point(|&t| t < t_end_ns);
        Some(Central {
            first,
            t_start_ns,
            t_end_ns,
            events: lo..hi,
        })
    }

    fn fields() -> Fields {
        Fields::from(vec![
            Field::new("spikes", DataType::LargeBinary, false),
            Field::new(
                "events",
                DataType::LargeList(Arc::new(Field::new(
                    "item",
                    DataType::Struct(EventBatch::event_fields()),
                    true,
                ))),
                false,
            ),
        ])
    }
}

/// Copies `n` bits from bit `from` of `src` to bit `to` of `dst` (bit `k` is bit `k % 8` of
/// byte `k / 8`, as the planes are packed); whole bytes at once where both offsets are
/// byte-aligned.
fn copy_bits(src: &[u8], from: usize, dst: &mut [u8], to: usize, n: usize) {
    let mut k = 0;
    if from.is_multiple_of(8) && to.is_multiple_of(8) {
        let bytes = n / 8;
        dst[to / 8..to / 8 + bytes].copy_from_slice(&src[from / 8..from / 8 + bytes]);
        k = bytes * 8;
    }
    for k in k..n {
        let (a, b) = (from + k, to + k);
        let bit = (src[a / 8] >> (a % 8)) & 1;
        dst[b / 8] = (dst[b / 8] & !(1 << (b % 8))) | (bit << (b % 8));
    }
}

impl Message for AlignedWindow {
    const TYPE_URN: &'static str = "neuspike/messages/v1/AlignedWindow";

    fn data_type() -> DataType {
        DataType::Struct(Self::fields())
    }

    fn to_arrow(&self) -> (Meta, ArrayRef) {
        let mut m = self.spikes.header();
        m.set_int(meta::T_REF_NS, self.t_ref_ns);
        m.set_int(meta::REF_PLANE, self.ref_plane as i64);
        m.set_int(meta::T_START_NS, self.events.t_start_ns);
        m.set_int(meta::T_END_NS, self.events.t_end_ns);
        m.set_int("event_width", int_of(self.events.width));
        m.set_int("event_height", int_of(self.events.height));
        let spikes = LargeBinaryArray::from_iter_values([self.spikes.bits.as_slice()]);
        let events = self.events.to_struct_array();
        let list = LargeListArray::new(
            Arc::new(Field::new(
                "item",
                DataType::Struct(EventBatch::event_fields()),
                true,
            )),
            OffsetBuffer::from_lengths([events.len()]),
            Arc::new(events),
            None,
        );
        let s = StructArray::new(Self::fields(), vec![Arc::new(spikes), Arc::new(list)], None);
        (m, Arc::new(s))
    }

    fn from_arrow(m: &Meta, data: &ArrayRef) -> Result<Self, SchemaError> {
        check_type(NAME, &Self::data_type(), data.data_type())?;
        let incons = |what: String| SchemaError::Inconsistent {
            message: NAME,
            what,
        };
        let s = data
            .as_any()
            .downcast_ref::<StructArray>()
            .ok_or_else(|| incons("payload is not a struct".into()))?;
        if s.len() != 1 {
            return Err(incons(format!("payload has {} rows, expected 1", s.len())));
        }
        let width = m.size(NAME, meta::WIDTH)?;
        let height = m.size(NAME, meta::HEIGHT)?;
        let n_planes = m.size(NAME, meta::N_PLANES)?;
        let plane_period_ns = m.int(NAME, meta::PLANE_PERIOD_NS)?;
        if plane_period_ns <= 0 || width == 0 || height == 0 || n_planes == 0 {
            return Err(incons(format!(
                "bad geometry: {n_planes} planes of {width}x{height} every {plane_period_ns} ns"
            )));
        }
        let bin = s
            .column(0)
            .as_any()
            .downcast_ref::<LargeBinaryArray>()
            .ok_or_else(|| incons("column `spikes` is not LargeBinary".into()))?;
        let bits = bin.value(0).to_vec();
        let expected = n_planes.saturating_mul(bytes_per_plane(width, height));
        if bits.len() != expected {
            return Err(incons(format!(
                "spikes hold {} bytes, header says {n_planes} planes of {width}x{height} = {expected}",
                bits.len()
            )));
        }
        let spikes = SpikeChunk {
            width,
            height,
            first_plane: m.uint(NAME, meta::FIRST_PLANE)?,
            n_planes,
            t_first_ns: m.int(NAME, meta::T_FIRST_NS)?,
            plane_period_ns,
            seq: m.uint(NAME, meta::SEQ)?,
            bits,
            lum_per_rate: m.lum_per_rate(NAME)?,
        };
        let ref_plane = m.uint(NAME, meta::REF_PLANE)?;
        if ref_plane < spikes.first_plane || ref_plane >= spikes.first_plane + n_planes as u64 {
            return Err(incons(format!(
                "ref_plane {ref_plane} outside the window's planes {}..{}",
                spikes.first_plane,
                spikes.first_plane + n_planes as u64
            )));
        }
        let list = s
            .column(1)
            .as_any()
            .downcast_ref::<LargeListArray>()
            .ok_or_else(|| incons("column `events` is not a LargeList".into()))?;
        let inner = list.value(0);
        let ev = inner
            .as_any()
            .downcast_ref::<StructArray>()
            .ok_or_else(|| incons("events are not structs".into()))?;
        let mut events = EventBatch {
            width: m.size(NAME, "event_width")?,
            height: m.size(NAME, "event_height")?,
            t_start_ns: m.int(NAME, meta::T_START_NS)?,
            t_end_ns: m.int(NAME, meta::T_END_NS)?,
            seq: spikes.seq,
            ..Default::default()
        };
        events.fill_from_struct(NAME, ev)?;
        Ok(AlignedWindow {
            t_ref_ns: m.int(NAME, meta::T_REF_NS)?,
            ref_plane,
            spikes,
            events,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::Event;

    #[test]
    fn round_trip() {
        let spikes = SpikeChunk {
            width: 4,
            height: 2,
            first_plane: 10,
            n_planes: 3,
            t_first_ns: 500,
            plane_period_ns: 50,
            seq: 7,
            bits: vec![1, 2, 3],
            lum_per_rate: Some(1.5),
        };
        let mut events = EventBatch::empty(4, 2, 450, 650, 7);
        events.push(Event {
            t_ns: 455,
            x: 3,
            y: 1,
            polarity: -1,
        });
        let w = AlignedWindow {
            t_ref_ns: 550,
            ref_plane: 11,
            spikes,
            events,
        };
        let (m, a) = w.to_arrow();
        assert_eq!(AlignedWindow::from_arrow(&m, &a).unwrap(), w);
        assert_eq!(w.ref_index(), 1);
        let mut bad = m.clone();
        bad.set_int(meta::REF_PLANE, 13);
        assert!(
            AlignedWindow::from_arrow(&bad, &a)
                .unwrap_err()
                .to_string()
                .contains("ref_plane 13")
        );
    }

    #[test]
    fn a_crop_is_the_window_align_cuts_around_the_same_reference() {
        // 8 planes of 8 pixels (one byte each), plane k's byte = k; reference plane 4 of 8.
        let spikes = SpikeChunk {
            width: 8,
            height: 1,
            first_plane: 100,
            n_planes: 8,
            t_first_ns: 1_000,
            plane_period_ns: 10,
            seq: 3,
            bits: (0..8).collect(),
            lum_per_rate: Some(2.0),
        };
        let mut events = EventBatch::empty(8, 1, 990, 1_070, 3);
        for t in [990, 1_005, 1_019, 1_020, 1_045, 1_050, 1_069] {
            events.push(Event {
                t_ns: t,
                x: 0,
                y: 0,
                polarity: 1,
            });
        }
        let w = AlignedWindow {
            t_ref_ns: 1_040,
            ref_plane: 104,
            spikes,
            events,
        };
        // 3 planes: 103..=105, events of [1_020, 1_050).
        let c = w.crop(3).expect("fits");
        assert_eq!((c.spikes.first_plane, c.spikes.n_planes), (103, 3));
        assert_eq!(c.spikes.bits, [3, 4, 5]);
        assert_eq!(c.spikes.t_first_ns, 1_030);
        assert_eq!((c.ref_plane, c.ref_index(), c.t_ref_ns), (104, 1, 1_040));
        assert_eq!((c.events.t_start_ns, c.events.t_end_ns), (1_020, 1_050));
        assert_eq!(c.events.t_ns, [1_020, 1_045]);
        assert_eq!(c.spikes.lum_per_rate, Some(2.0));
        // 4 planes: 102..=105 (an even window has one more plane before).
        assert_eq!(w.crop(4).expect("fits").spikes.bits, [2, 3, 4, 5]);
        // The whole window is itself; more planes than it holds, or none, is no window.
        assert_eq!(w.crop(8).expect("whole"), w);
        assert_eq!(w.crop(9), None);
        assert_eq!(w.crop(0), None);
        // Where it lies, without a copy: planes from index 3, events 3..5 of the window's.
        let span = w.central(3).expect("fits");
        assert_eq!((span.first, span.events.clone()), (3, 3..5));
        assert_eq!((span.t_start_ns, span.t_end_ns), (1_020, 1_050));
        assert_eq!(w.central(9), None);
        // Without the events: the same planes and span, no event.
        let s = w.crop_spikes(3).expect("fits");
        assert_eq!(s.spikes, c.spikes);
        assert_eq!((s.events.t_start_ns, s.events.t_end_ns), (1_020, 1_050));
        assert_eq!((s.events.width, s.events.height, s.events.len()), (8, 1, 0));
        assert_eq!(w.crop_spikes(0), None);
    }

    proptest::proptest! {
        #[test]
        fn a_region_holds_the_pixels_and_events_that_fall_in_it(
            width in 1usize..40, height in 1usize..12, n in 1usize..4, seed in proptest::prelude::any::<u64>(),
            x0 in 0usize..40, y0 in 0usize..12, rw in 1usize..40, rh in 1usize..12,
        ) {
            let per = bytes_per_plane(width, height);
            let mut r = seed | 1;
            let mut next = || { r ^= r << 13; r ^= r >> 7; r ^= r << 17; r };
            let bits: Vec<u8> = (0..n * per).map(|_| next() as u8).collect();
            let mut events = EventBatch::empty(width, height, 0, 1_000, 3);
            for i in 0..20 {
                events.push(Event {
                    t_ns: i * 10,
                    x: (next() % width as u64) as u16,
                    y: (next() % height as u64) as u16,
                    polarity: if next() % 2 == 0 { 1 } else { -1 },
                });
            }
            let w = AlignedWindow {
                t_ref_ns: 0,
                ref_plane: 0,
                spikes: SpikeChunk {
                    width, height, first_plane: 0, n_planes: n, t_first_ns: 0,
                    plane_period_ns: 50, seq: 3, bits, lum_per_rate: None,
                },
                events,
            };
            let got = w.region(x0, y0, rw, rh, true);
            proptest::prop_assert_eq!(got.is_some(), x0 + rw <= width && y0 + rh <= height);
            let Some(got) = got else { return Ok(()) };
            let bit = |b: &[u8], k: usize| (b[k / 8] >> (k % 8)) & 1;
            let per_out = bytes_per_plane(rw, rh);
            for p in 0..n {
                for y in 0..rh {
                    for x in 0..rw {
                        proptest::prop_assert_eq!(
                            bit(&got.spikes.bits[p * per_out..], y * rw + x),
                            bit(&w.spikes.bits[p * per..], (y0 + y) * width + x0 + x)
                        );
                    }
                }
            }
            let inside: Vec<(i64, u16, u16, i8)> = (0..w.events.len())
                .filter(|&i| (x0..x0 + rw).contains(&usize::from(w.events.x[i]))
                    && (y0..y0 + rh).contains(&usize::from(w.events.y[i])))
                .map(|i| (w.events.t_ns[i], w.events.x[i] - x0 as u16, w.events.y[i] - y0 as u16, w.events.polarity[i]))
                .collect();
            let kept: Vec<(i64, u16, u16, i8)> = (0..got.events.len())
                .map(|i| (got.events.t_ns[i], got.events.x[i], got.events.y[i], got.events.polarity[i]))
                .collect();
            proptest::prop_assert_eq!(kept, inside);
            proptest::prop_assert_eq!((got.events.width, got.events.height), (rw, rh));
            proptest::prop_assert_eq!(w.region(x0, y0, rw, rh, false).map(|r| r.events.len()), Some(0));
        }
    }
}
