//! Prophesee EVT 3.0: 16-bit little-endian words, the type in the 4 most significant bits. The
//! encoding is stateful: a word sets the row, the time or the base column that later words use.
//!
//! | type | name | payload |
//! |---|---|---|
//! | `0000` | EVT_ADDR_Y | `[10:0]` row, `[11]` system type (ignored) |
//! | `0010` | EVT_ADDR_X | `[10:0]` column, `[11]` polarity: one event |
//! | `0011` | VECT_BASE_X | `[10:0]` base column, `[11]` polarity for the vectors after it |
//! | `0100` | VECT_12 | `[11:0]` valid bits: events at base + i; base += 12 |
//! | `0101` | VECT_8 | `[7:0]` valid bits: events at base + i; base += 8 |
//! | `0110` | EVT_TIME_LOW | `[11:0]` bits 0..11 of the µs time |
//! | `0111` | CONTINUED_4 | extra data (skipped, counted) |
//! | `1000` | EVT_TIME_HIGH | `[11:0]` bits 12..23 of the µs time |
//! | `1010` | EXT_TRIGGER | `[0]` value, `[11:8]` channel (counted) |
//! | `1110` | OTHERS | extensions (skipped, counted) |
//! | `1111` | CONTINUED_12 | extra data (skipped, counted) |
//!
//! Other types are reserved ([`crate::UnknownWords`]).
//!
//! Time: `time_high << 12 | time_low` µs on a 24-bit clock that wraps every 2^24 µs (16.8 s). A
//! `TIME_HIGH` at least 2^11 steps below its predecessor is a wrap (adds 2^24 µs), as in
//! Prophesee's decoder; a `TIME_HIGH` that changes the high bits resets the low bits to 0 until
//! the next `TIME_LOW`. A `TIME_LOW` below the previous one under the same `TIME_HIGH` is taken
//! literally, without an implied carry (Prophesee's convention too): the events after it are
//! earlier than those before, and [`crate::Disorder`] decides (error by default, or clamp and
//! count). Events before the first `TIME_HIGH` or the first `EVT_ADDR_Y`, and vector words before
//! any `VECT_BASE_X`, are dropped and counted in
//! [`crate::ReadStats::events_without_time_base`].

use std::io::Write;

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Out, WriteSummary, ns_to_us, us_to_ns};
use crate::error::{Location, Result};
use crate::events::{Resolution, Sink};
use crate::evt2::{check_event, raw_header};

/// Bytes per word.
pub const WORD_BYTES: usize = 2;
/// The sensor clock's period: times are carried modulo 2^24 µs (16.8 s). A file's absolute start
/// time is therefore known only modulo this period: a reader starts counting wraps at 0.
pub const CLOCK_PERIOD_US: u64 = 1 << 24;
/// Word types.
pub mod word {
    /// Row.
    pub const ADDR_Y: u8 = 0x0;
    /// Column and polarity of one event.
    pub const ADDR_X: u8 = 0x2;
    /// Base column and polarity of the vectors after it.
    pub const VECT_BASE_X: u8 = 0x3;
    /// 12 events' valid bits.
    pub const VECT_12: u8 = 0x4;
    /// 8 events' valid bits.
    pub const VECT_8: u8 = 0x5;
    /// Bits 0..11 of the time.
    pub const TIME_LOW: u8 = 0x6;
    /// 4 bits of extra data.
    pub const CONTINUED_4: u8 = 0x7;
    /// Bits 12..23 of the time.
    pub const TIME_HIGH: u8 = 0x8;
    /// External trigger.
    pub const EXT_TRIGGER: u8 = 0xA;
    /// Extensions.
    pub const OTHERS: u8 = 0xE;
    /// 12 bits of extra data.
    pub const CONTINUED_12: u8 = 0xF;
}
const COORD_MASK: u32 = (1 << 11) - 1;
const POLARITY_BIT: u32 = 1 << 11;
const TIME_BITS: u32 = 12;
const TIME_MASK: u32 = (1 << TIME_BITS) - 1;
/// A `TIME_HIGH` this many steps below its predecessor (or more) is a wrap.
const WRAP_THRESHOLD: u32 = 1 << (TIME_BITS - 1);

/// Decoder state across buffers.
#[derive(Debug, Default)]
pub(crate) struct Evt3Decoder {
    high: Option<u32>,
    low: u32,
    wraps: u64,
    y: Option<u32>,
    base_x: Option<u32>,
    base_on: bool,
}

impl Evt3Decoder {
    fn t_us(&self) -> Option<u64> {
        let high = self.high?;
        Some((self.wraps << (2 * TIME_BITS)) | (u64::from(high) << TIME_BITS) | u64::from(self.low))
    }

    /// Decodes whole words of `bytes` (which start at file offset `offset`) until the sink is
    /// full; returns the bytes consumed.
    pub(crate) fn decode(
        &mut self,
        bytes: &[u8],
        offset: u64,
        sink: &mut Sink,
        out: &mut EventBatch,
    ) -> Result<usize> {
        let mut consumed = 0usize;
        for w in bytes.chunks_exact(WORD_BYTES) {
            if sink.full() {
                break;
            }
            let word = u16::from_le_bytes([w[0], w[1]]);
            let at = offset + consumed as u64;
            consumed += WORD_BYTES;
            let kind = (word >> 12) as u8;
            let payload = u32::from(word) & 0xFFF;
            match kind {
                word::ADDR_Y => self.y = Some(payload & COORD_MASK),
                word::ADDR_X => match (self.t_us(), self.y) {
                    (Some(t_us), Some(y)) => {
                        let t_ns = us_to_ns(t_us, &sink.path, at)?;
                        let on = payload & POLARITY_BIT != 0;
                        sink.emit(out, t_ns, payload & COORD_MASK, y, on, Location::Byte(at))?;
                    }
                    _ => sink.stats.events_without_time_base += 1,
                },
                word::VECT_BASE_X => {
                    self.base_x = Some(payload & COORD_MASK);
                    self.base_on = payload & POLARITY_BIT != 0;
                }
                word::VECT_12 | word::VECT_8 => {
                    let n = if kind == word::VECT_12 { 12 } else { 8 };
                    let mut valid = payload & ((1 << n) - 1);
                    match (self.t_us(), self.y, self.base_x) {
                        (Some(t_us), Some(y), Some(base)) => {
                            let t_ns = us_to_ns(t_us, &sink.path, at)?;
                            while valid != 0 {
                                let i = valid.trailing_zeros();
                                valid &= valid - 1;
                                sink.emit(
                                    out,
                                    t_ns,
                                    base + i,
                                    y,
                                    self.base_on,
                                    Location::Byte(at),
                                )?;
                            }
                        }
                        _ => sink.stats.events_without_time_base += u64::from(valid.count_ones()),
                    }
                    if let Some(b) = &mut self.base_x {
                        *b = b.saturating_add(n);
                    }
                }
                word::TIME_LOW => self.low = payload,
                word::TIME_HIGH => {
                    if let Some(h) = self.high {
                        if payload < h && h - payload >= WRAP_THRESHOLD {
                            self.wraps += 1;
                            sink.stats.time_wraps += 1;
                        }
                        if payload != h {
                            self.low = 0;
                        }
                    }
                    self.high = Some(payload);
                }
                word::EXT_TRIGGER => sink.stats.triggers += 1,
                word::CONTINUED_4 | word::CONTINUED_12 | word::OTHERS => {
                    sink.stats.skipped_words += 1;
                }
                _ => sink.unknown_word(at, "EVT 3.0", kind, u32::from(word))?,
            }
        }
        Ok(consumed)
    }
}

/// Pixels one `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group covers.
const VECTOR_SPAN: u16 = 32;

/// Writes events as a Prophesee RAW EVT 3.0 file: a `%` header, then `TIME_HIGH`/`TIME_LOW`/
/// `EVT_ADDR_Y` words when the time or row changes, and for each event either an `EVT_ADDR_X`, or,
/// when at least two consecutive events share time, row and polarity with increasing columns
/// within 32 pixels, one `VECT_BASE_X, VECT_12, VECT_12, VECT_8` group (the grouping Prophesee's
/// decoder expects). Times are floored to microseconds and wrap every 2^24 µs
/// ([`CLOCK_PERIOD_US`]), as on the sensor, with extra `TIME_HIGH` words over long gaps so that a
/// reader can always tell a wrap from a jump. The format has no field for whole periods, so
/// reading the file back gives times modulo [`CLOCK_PERIOD_US`] at its start (later wraps are
/// undone).
pub struct Evt3Writer<W: Write> {
    out: Out<W>,
    resolution: Resolution,
    last_t_us: Option<u64>,
    last_high: Option<u64>,
    last_low: Option<u32>,
    last_y: Option<u16>,
    summary: WriteSummary,
}

impl<W: Write> Evt3Writer<W> {
    /// Starts a file on `w` (named `name` in errors) for a sensor of `resolution` (at most
    /// 2048x2048, the format's limit).
    pub fn new(w: W, name: impl Into<std::path::PathBuf>, resolution: Resolution) -> Result<Self> {
        let mut out = Out::new(w, name.into());
        if u32::from(resolution.width) > COORD_MASK + 1
            || u32::from(resolution.height) > COORD_MASK + 1
        {
            return Err(out.unwritable(
                0,
                format!("resolution {resolution} exceeds EVT 3.0's 2048x2048"),
            ));
        }
        out.put(raw_header("3.0", "EVT3", resolution).as_bytes())?;
        Ok(Evt3Writer {
            out,
            resolution,
            last_t_us: None,
            last_high: None,
            last_low: None,
            last_y: None,
            summary: WriteSummary::default(),
        })
    }

    fn put(&mut self, kind: u8, payload: u32) -> Result<()> {
        let w = (u16::from(kind) << 12) | (payload & 0xFFF) as u16;
        self.out.put(&w.to_le_bytes())
    }

    /// Checks event `e` (the `index`-th written) and emits the time and row words it needs.
    fn prepare(&mut self, e: &Event) -> Result<u64> {
        let index = self.summary.items;
        let (t_us, floored) = ns_to_us(&self.out, index, e.t_ns)?;
        check_event(&self.out, index, e, self.resolution, self.last_t_us, t_us)?;
        self.summary.floored_timestamps += u64::from(floored);
        let high = t_us >> TIME_BITS;
        // Keep consecutive TIME_HIGH words less than half the clock range apart.
        const STEP: u64 = 1 << (TIME_BITS - 2);
        if let Some(mut last) = self.last_high {
            while high - last > STEP {
                last += STEP;
                self.put(word::TIME_HIGH, last as u32)?;
                self.last_low = Some(0);
            }
        }
        if self.last_high != Some(high) {
            self.put(word::TIME_HIGH, high as u32)?;
            self.last_high = Some(high);
            self.last_low = Some(0);
        }
        let low = (t_us as u32) & TIME_MASK;
        if self.last_low != Some(low) {
            self.put(word::TIME_LOW, low)?;
            self.last_low = Some(low);
        }
        if self.last_y != Some(e.y) {
            self.put(word::ADDR_Y, u32::from(e.y))?;
            self.last_y = Some(e.y);
        }
        self.last_t_us = Some(t_us);
        Ok(t_us)
    }

    /// Appends one event; events must come in non-decreasing time order.
    pub fn write_event(&mut self, e: &Event) -> Result<()> {
        self.prepare(e)?;
        let pol = if e.polarity > 0 { POLARITY_BIT } else { 0 };
        self.put(word::ADDR_X, u32::from(e.x) | pol)?;
        self.summary.items += 1;
        Ok(())
    }

    /// Appends every event of a batch, vectorising runs.
    pub fn write_batch(&mut self, b: &EventBatch) -> Result<()> {
        let n = b.len();
        let mut i = 0;
        while i < n {
            let e = b.get(i);
            // The run of events after `e` that one vector group can carry.
            let mut j = i + 1;
            let mut prev_x = e.x;
            while j < n
                && b.t_ns[j] == e.t_ns
                && b.y[j] == e.y
                && b.polarity[j] == e.polarity
                && b.x[j] > prev_x
                && b.x[j] - e.x < VECTOR_SPAN
            {
                prev_x = b.x[j];
                j += 1;
            }
            if j - i < 2 {
                self.write_event(&e)?;
                i += 1;
                continue;
            }
            self.prepare(&e)?;
            if e.t_ns % 1000 != 0 {
                self.summary.floored_timestamps += (j - i - 1) as u64;
            }
            for k in i + 1..j {
                // Checked like any event (bounds, polarity); time and row are e's.
                let ek = b.get(k);
                check_event(
                    &self.out,
                    self.summary.items + (k - i) as u64,
                    &ek,
                    self.resolution,
                    None,
                    0,
                )?;
            }
            let mut mask = 0u32;
            for k in i..j {
                mask |= 1 << (b.x[k] - e.x);
            }
            let pol = if e.polarity > 0 { POLARITY_BIT } else { 0 };
            self.put(word::VECT_BASE_X, u32::from(e.x) | pol)?;
            self.put(word::VECT_12, mask & 0xFFF)?;
            self.put(word::VECT_12, (mask >> 12) & 0xFFF)?;
            self.put(word::VECT_8, (mask >> 24) & 0xFF)?;
            self.summary.items += (j - i) as u64;
            i = j;
        }
        Ok(())
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

impl<W: Write> crate::EventWriter for Evt3Writer<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        Evt3Writer::write_event(self, e)
    }

    fn write_batch(&mut self, b: &EventBatch) -> Result<()> {
        Evt3Writer::write_batch(self, b)
    }
}
