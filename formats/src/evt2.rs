//! Prophesee EVT 2.0: 32-bit little-endian words, the type in the 4 most significant bits.
//!
//! | type | name | payload |
//! |---|---|---|
//! | `0000` | CD_OFF | `[27:22]` time low 6 bits, `[21:11]` x, `[10:0]` y; polarity 0 |
//! | `0001` | CD_ON | as CD_OFF; polarity 1 |
//! | `1000` | EVT_TIME_HIGH | `[27:0]` bits 6..33 of the µs time |
//! | `1010` | EXT_TRIGGER | `[27:22]` time low, `[12:8]` channel, `[0]` value (counted) |
//! | `1110` | OTHERS | extensions (skipped, counted) |
//! | `1111` | CONTINUED | extra data of a previous word (skipped, counted) |
//!
//! Any other type is reserved ([`crate::UnknownWords`]). An event's time is
//! `time_high << 6 | time_low` microseconds. The 34-bit clock wraps after 2^34 µs (4 h 46 min):
//! a `TIME_HIGH` more than half the range (2^27 steps) below its predecessor is a wrap and adds
//! 2^34 µs to all later times; a smaller step back is not, and the events after it are handled by
//! [`crate::Disorder`]. CD words before the first `TIME_HIGH` have no time and are dropped and
//! counted ([`crate::ReadStats::events_without_time_base`]), as Prophesee's own decoder does.

use std::io::Write;

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Out, WriteSummary, ns_to_us, us_to_ns};
use crate::error::{FormatError, Location, Result};
use crate::events::{Resolution, Sink};

/// Bytes per word.
pub const WORD_BYTES: usize = 4;
/// The sensor clock's period: times are carried modulo 2^34 µs (4 h 46 min). A reader starts
/// counting wraps at 0, so a file's absolute start time is known only modulo this period.
pub const CLOCK_PERIOD_US: u64 = 1 << 34;
/// Word types.
pub mod word {
    /// OFF change-detection event.
    pub const CD_OFF: u8 = 0x0;
    /// ON change-detection event.
    pub const CD_ON: u8 = 0x1;
    /// Bits 6..33 of the time base.
    pub const TIME_HIGH: u8 = 0x8;
    /// External trigger.
    pub const EXT_TRIGGER: u8 = 0xA;
    /// Extensions.
    pub const OTHERS: u8 = 0xE;
    /// Continuation of a previous word.
    pub const CONTINUED: u8 = 0xF;
}
const TIME_LOW_BITS: u32 = 6;
const TIME_HIGH_BITS: u32 = 28;
const TIME_HIGH_MASK: u32 = (1 << TIME_HIGH_BITS) - 1;
/// A drop of more than this many `TIME_HIGH` steps is a clock wrap.
const WRAP_THRESHOLD: u32 = 1 << (TIME_HIGH_BITS - 1);
/// Largest coordinate a word can hold.
pub const MAX_COORD: u32 = (1 << 11) - 1;

/// Decoder state across buffers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Evt2Decoder {
    /// `time_high << 6` in µs, wraps included; `None` before the first `TIME_HIGH`.
    base_us: Option<u64>,
    last_high: u32,
    wraps: u64,
}

impl Evt2Decoder {
    /// Decodes whole words of `bytes` (which start at file offset `offset`) until the sink is
    /// full; returns the bytes consumed.
    ///
    /// Runs of events and time bases go through [`Evt2Decoder::decode_fast`], a block at a time,
    /// and the sink checks each block's events in column passes ([`Sink::accept_block`]). A block
    /// the sink refuses is taken back (events and decoder state) and decoded again by
    /// [`Evt2Decoder::decode_checked`], word by word, which names the fault or repairs it; so
    /// does every word the fast path leaves.
    pub(crate) fn decode(
        &mut self,
        bytes: &[u8],
        offset: u64,
        sink: &mut Sink,
        out: &mut EventBatch,
    ) -> Result<usize> {
        sink.decode_blocks::<_, WORD_BYTES>(
            bytes,
            offset,
            self,
            out,
            |d: &mut Self, b: &[u8], out: &mut EventBatch, max| d.decode_fast(b, out, max),
            |d, b, at, sink, out| d.decode_checked(b, at, sink, out),
        )
    }

    /// The fast path: decodes the events and time bases at the start of `bytes` straight into
    /// `out`'s columns, at most `max_events` events, and returns the bytes consumed; its state
    /// then stands after them. It stops before any word the checked path must see: another type,
    /// a clock wrap, or an event without a time base. Coordinates and the time order are for the
    /// sink to check. The polarity comes from the type without a branch (ON and OFF follow no
    /// pattern); the one branch, event or time base, goes the same way for runs of events.
    #[inline(never)]
    fn decode_fast(&mut self, bytes: &[u8], out: &mut EventBatch, max_events: usize) -> usize {
        let Some(mut base_us) = self.base_us else {
            return 0;
        };
        // Every time before the next wrap fits `i64` ns: checked once, here.
        let fits = (self.wraps + 1)
            .checked_mul(CLOCK_PERIOD_US)
            .and_then(|end_us| end_us.checked_mul(1000))
            .is_some_and(|end_ns| i64::try_from(end_ns).is_ok());
        let kind_of = |w: &[u8]| w[3] >> 4;
        let fast_kind = |k: u8| matches!(k, word::CD_OFF | word::CD_ON | word::TIME_HIGH);
        if !fits || bytes.len() < WORD_BYTES || !fast_kind(kind_of(bytes)) {
            return 0;
        }
        let wrap_base_us = self.wraps * CLOCK_PERIOD_US;
        let mut last_high = self.last_high;
        let mut base_ns = base_us as i64 * 1000;
        // The columns are grown by the block's room first and cut back after: each event is then
        // four stores, without a capacity check each.
        let start = out.len();
        let cap = start + max_events;
        out.resize(cap);
        let (ts, xs, ys, ps) = (
            &mut out.t_ns[..cap],
            &mut out.x[..cap],
            &mut out.y[..cap],
            &mut out.polarity[..cap],
        );
        let mut n = start;
        let mut used = 0usize;
        for w in bytes.chunks_exact(WORD_BYTES) {
            let word = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            let kind = (word >> 28) as u8;
            if kind <= word::CD_ON {
                if n == cap {
                    break;
                }
                // x, y < 2,048: both fit u16; CD_OFF (0) is -1, CD_ON (1) is +1.
                ts[n] = base_ns + i64::from((word >> 22) & 0x3F) * 1000;
                xs[n] = ((word >> 11) & MAX_COORD) as u16;
                ys[n] = (word & MAX_COORD) as u16;
                ps[n] = 2 * kind as i8 - 1;
                n += 1;
            } else if kind == word::TIME_HIGH {
                let high = word & TIME_HIGH_MASK;
                if high < last_high && last_high - high > WRAP_THRESHOLD {
                    break;
                }
                last_high = high;
                base_us = wrap_base_us + (u64::from(high) << TIME_LOW_BITS);
                base_ns = base_us as i64 * 1000;
            } else {
                break;
            }
            used += 1;
        }
        out.truncate(n);
        (self.base_us, self.last_high) = (Some(base_us), last_high);
        used * WORD_BYTES
    }

    /// The checked path: decodes whole words of `bytes` (which start at file offset `offset`)
    /// one by one, each event through [`Sink::emit`], until the sink is full; returns the bytes
    /// consumed.
    fn decode_checked(
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
            let word = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            let at = offset + consumed as u64;
            consumed += WORD_BYTES;
            let kind = (word >> 28) as u8;
            match kind {
                word::CD_OFF | word::CD_ON => {
                    let Some(base) = self.base_us else {
                        sink.stats.events_without_time_base += 1;
                        continue;
                    };
                    let t_us = base | u64::from((word >> 22) & 0x3F);
                    let t_ns = us_to_ns(t_us, &sink.path, at)?;
                    sink.emit(
                        out,
                        t_ns,
                        (word >> 11) & MAX_COORD,
                        word & MAX_COORD,
                        kind == word::CD_ON,
                        Location::Byte(at),
                    )?;
                }
                word::TIME_HIGH => {
                    let high = word & TIME_HIGH_MASK;
                    if self.base_us.is_some()
                        && high < self.last_high
                        && self.last_high - high > WRAP_THRESHOLD
                    {
                        self.wraps += 1;
                        sink.stats.time_wraps += 1;
                    }
                    self.last_high = high;
                    let base = self
                        .wraps
                        .checked_mul(CLOCK_PERIOD_US)
                        .and_then(|w| w.checked_add(u64::from(high) << TIME_LOW_BITS));
                    let Some(base) = base else {
                        return Err(FormatError::Corrupt {
                            path: sink.path.clone(),
                            offset: at,
                            what: format!("{} clock wraps overflow the time base", self.wraps),
                        });
                    };
                    self.base_us = Some(base);
                }
                word::EXT_TRIGGER => sink.stats.triggers += 1,
                word::OTHERS | word::CONTINUED => sink.stats.skipped_words += 1,
                _ => sink.unknown_word(at, "EVT 2.0", kind, word)?,
            }
        }
        Ok(consumed)
    }
}

/// The `%` header a RAW writer puts before its words.
pub(crate) fn raw_header(evt: &str, short: &str, r: Resolution) -> String {
    format!(
        "% evt {evt}\n% format {short};height={h};width={w}\n% geometry {w}x{h}\n% end\n",
        w = r.width,
        h = r.height
    )
}

/// Writes events as a Prophesee RAW EVT 2.0 file: a `%` header (`evt 2.0`, `format`, `geometry`,
/// `end`), then one `TIME_HIGH` word whenever bits 6.. of the time change, and one CD word per
/// event. Times are floored to microseconds (counted in [`WriteSummary::floored_timestamps`]);
/// the 34-bit clock wraps as the sensor's does ([`CLOCK_PERIOD_US`]), with extra `TIME_HIGH`
/// words over long gaps so that a reader can always tell a wrap from a jump. Times at or past the
/// first period come back modulo [`CLOCK_PERIOD_US`] at the start of the file.
pub struct Evt2Writer<W: Write> {
    out: Out<W>,
    resolution: Resolution,
    last_t_us: Option<u64>,
    last_high: Option<u64>,
    summary: WriteSummary,
}

impl<W: Write> Evt2Writer<W> {
    /// Starts a file on `w` (named `name` in errors) for a sensor of `resolution` (at most
    /// 2048x2048, the format's limit).
    pub fn new(w: W, name: impl Into<std::path::PathBuf>, resolution: Resolution) -> Result<Self> {
        let mut out = Out::new(w, name.into());
        if u32::from(resolution.width) > MAX_COORD + 1
            || u32::from(resolution.height) > MAX_COORD + 1
        {
            return Err(out.unwritable(
                0,
                format!("resolution {resolution} exceeds EVT 2.0's 2048x2048"),
            ));
        }
        out.put(raw_header("2.0", "EVT2", resolution).as_bytes())?;
        Ok(Evt2Writer {
            out,
            resolution,
            last_t_us: None,
            last_high: None,
            summary: WriteSummary::default(),
        })
    }

    fn put_word(&mut self, word: u32) -> Result<()> {
        self.out.put(&word.to_le_bytes())
    }

    /// Appends one event; events must come in non-decreasing time order.
    pub fn write_event(&mut self, e: &Event) -> Result<()> {
        let index = self.summary.items;
        let (t_us, floored) = ns_to_us(&self.out, index, e.t_ns)?;
        check_event(&self.out, index, e, self.resolution, self.last_t_us, t_us)?;
        let high = t_us >> TIME_LOW_BITS;
        // Keep consecutive TIME_HIGH words less than half the clock range apart.
        const STEP: u64 = 1 << (TIME_HIGH_BITS - 2);
        if let Some(mut last) = self.last_high {
            while high - last > STEP {
                last += STEP;
                self.put_word((u32::from(word::TIME_HIGH) << 28) | (last as u32 & TIME_HIGH_MASK))?;
            }
        }
        if self.last_high != Some(high) {
            self.put_word((u32::from(word::TIME_HIGH) << 28) | (high as u32 & TIME_HIGH_MASK))?;
            self.last_high = Some(high);
        }
        let kind = if e.polarity > 0 {
            word::CD_ON
        } else {
            word::CD_OFF
        };
        let w = (u32::from(kind) << 28)
            | (((t_us & 0x3F) as u32) << 22)
            | (u32::from(e.x) << 11)
            | u32::from(e.y);
        self.put_word(w)?;
        self.last_t_us = Some(t_us);
        self.summary.items += 1;
        self.summary.floored_timestamps += u64::from(floored);
        Ok(())
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

/// Checks an event against the sensor, the polarity convention and the order of the stream.
pub(crate) fn check_event<W: Write>(
    out: &Out<W>,
    index: u64,
    e: &Event,
    r: Resolution,
    last_t_us: Option<u64>,
    t_us: u64,
) -> Result<()> {
    if e.x >= r.width || e.y >= r.height {
        return Err(out.unwritable(
            index,
            format!("({}, {}) is outside the {r} sensor", e.x, e.y),
        ));
    }
    if e.polarity != 1 && e.polarity != -1 {
        return Err(out.unwritable(index, format!("polarity {} is not +1 or -1", e.polarity)));
    }
    if let Some(last) = last_t_us
        && t_us < last
    {
        return Err(out.unwritable(
            index,
            format!("time {t_us} us is earlier than the previous event's {last} us"),
        ));
    }
    Ok(())
}

impl<W: Write> crate::EventWriter for Evt2Writer<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        Evt2Writer::write_event(self, e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::fast_vs_checked::{assert_same, decode_all, options};
    use proptest::prelude::*;

    /// A word: mostly events with coordinates a little past the 40x30 sensor, time bases that
    /// mostly rise (sometimes step back, sometimes wrap), and a few rare or unknown types.
    fn word() -> impl Strategy<Value = u32> {
        let cd = |kind: u32, low: u32, x: u32, y: u32| kind << 28 | low << 22 | x << 11 | y;
        prop_oneof![
            16 => (0u32..2, 0u32..64, 0u32..44, 0u32..34).prop_map(move |(k, t, x, y)| cd(k, t, x, y)),
            3 => (0u32..3).prop_map(|step| 0x8 << 28 | step),
            1 => prop_oneof![Just(0xA), Just(0xE), Just(0xF), Just(0x3)].prop_map(|k: u32| k << 28 | 5),
        ]
    }

    /// Time bases in order (each `TIME_HIGH` payload is a step), except now and then one that
    /// steps back a little or wraps.
    fn ordered(words: Vec<u32>) -> Vec<u8> {
        let mut high = 0u32;
        let mut out = Vec::new();
        for (i, w) in words.into_iter().enumerate() {
            let w = if w >> 28 == 0x8 {
                high = match i % 13 {
                    0 => high.saturating_sub(1),
                    5 => (high + WRAP_THRESHOLD + 7) & TIME_HIGH_MASK,
                    _ => (high + (w & 3)) & TIME_HIGH_MASK,
                };
                0x8 << 28 | high
            } else {
                w
            };
            out.extend_from_slice(&w.to_le_bytes());
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        /// The fast path gives what the checked path gives, word for word: the same events,
        /// statistics and error, whatever the requests' sizes and the buffers' boundaries.
        #[test]
        fn the_fast_path_matches_the_checked_one(
            words in prop::collection::vec(word(), 0..3000),
            max in 1usize..5000,
            piece in prop::sample::select(vec![4usize, 7, 64, 1 << 20]),
            clamp in any::<bool>(),
            skip_unknown in any::<bool>(),
        ) {
            let opts = options(clamp, skip_unknown);
            let bytes = ordered(words);
            let mut d = Evt2Decoder::default();
            let fast = decode_all(&bytes, max, piece, &opts, |b, at, sink, out| d.decode(b, at, sink, out));
            let mut d = Evt2Decoder::default();
            let checked =
                decode_all(&bytes, max, piece, &opts, |b, at, sink, out| d.decode_checked(b, at, sink, out));
            assert_same(&fast, &checked)?;
        }
    }

    #[test]
    fn a_clock_near_the_end_of_i64_leaves_the_fast_path() {
        let mut d = Evt2Decoder {
            base_us: Some(0),
            wraps: (i64::MAX / 1000) as u64 >> 34,
            ..Evt2Decoder::default()
        };
        let cd = (1u32 << 28 | 3 << 11 | 2).to_le_bytes();
        let mut out = EventBatch::default();
        assert_eq!(d.decode_fast(&cd, &mut out, 100), 0);
        d.wraps -= 1;
        assert_eq!(d.decode_fast(&cd, &mut out, 100), 4);
        assert_eq!((out.x[0], out.y[0], out.polarity[0]), (3, 2, 1));
    }
}
