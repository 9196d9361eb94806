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
#[derive(Debug, Default)]
pub(crate) struct Evt2Decoder {
    /// `time_high << 6` in µs, wraps included; `None` before the first `TIME_HIGH`.
    base_us: Option<u64>,
    last_high: u32,
    wraps: u64,
}

impl Evt2Decoder {
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
