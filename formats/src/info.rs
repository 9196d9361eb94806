//! Summaries of recordings: size, duration, counts, rates, first and last timestamps.

use std::fmt;
use std::path::{Path, PathBuf};

use neuspike_schemas::EventBatch;

use crate::error::Result;
use crate::events::{EventReader, ReadOptions, ReadStats, Resolution};
use crate::open::open_event_format;
use crate::pku::{self, PkuOptions, SpikeInfo};
use crate::sniff::{Format, sniff};

/// A summary of an event file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EventInfo {
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub format: Format,
    /// The sensor size, when the file or the options give it (the observed extent is in
    /// [`ReadStats::max_x`] and [`ReadStats::max_y`] either way).
    pub resolution: Option<Resolution>,
    /// Counts, first and last timestamps, repairs and skips.
    pub stats: ReadStats,
}

impl EventInfo {
    /// Last minus first timestamp.
    pub fn duration_ns(&self) -> i64 {
        self.stats.duration_ns()
    }

    /// Events per second over [`EventInfo::duration_ns`] (0 for a single instant).
    pub fn rate_per_s(&self) -> f64 {
        let d = self.duration_ns();
        if d <= 0 {
            0.0
        } else {
            self.stats.events as f64 * 1e9 / d as f64
        }
    }
}

impl fmt::Display for EventInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.stats;
        write!(f, "{}: {}", self.path.display(), self.format)?;
        match self.resolution {
            Some(r) => writeln!(f, ", {r}")?,
            None => writeln!(f, ", size not stated")?,
        }
        writeln!(
            f,
            "  {} events ({} ON, {} OFF), max x {}, max y {}",
            s.events,
            s.on_events,
            s.events - s.on_events,
            s.max_x,
            s.max_y
        )?;
        if let (Some(a), Some(b)) = (s.first_t_ns, s.last_t_ns) {
            writeln!(f, "  first t {a} ns, last t {b} ns, {} ns", b - a)?;
        }
        write!(f, "  {:.0} events/s", self.rate_per_s())?;
        let notes = [
            (s.clamped_timestamps, "timestamps clamped"),
            (s.duplicate_events, "duplicate events"),
            (s.time_wraps, "clock wraps undone"),
            (s.triggers, "trigger words"),
            (s.skipped_words, "words without events"),
            (s.unknown_words, "unknown words skipped"),
            (
                s.events_without_time_base,
                "events before the time base, dropped",
            ),
            (s.lines_skipped, "lines skipped"),
            (
                s.skipped_packets,
                "packets of other streams (frames, IMU, triggers)",
            ),
        ];
        for (n, what) in notes {
            if n > 0 {
                write!(f, "\n  {n} {what}")?;
            }
        }
        Ok(())
    }
}

/// Reads `reader` to the end, counting.
pub fn summarise(
    reader: &mut dyn EventReader,
    format: Format,
    resolution: Option<Resolution>,
) -> Result<EventInfo> {
    let mut scratch = EventBatch::default();
    loop {
        scratch.t_ns.clear();
        scratch.x.clear();
        scratch.y.clear();
        scratch.polarity.clear();
        if reader.read_into(&mut scratch, 1 << 16)? == 0 {
            break;
        }
    }
    Ok(EventInfo {
        path: reader.source().to_path_buf(),
        format,
        resolution,
        stats: reader.stats().clone(),
    })
}

/// A summary of the event file at `path` in `format`; files that state no size are summarised
/// anyway, with [`EventInfo::resolution`] `None`.
pub fn event_info(path: impl AsRef<Path>, format: Format, opts: &ReadOptions) -> Result<EventInfo> {
    let opts = ReadOptions {
        allow_unknown_size: true,
        ..opts.clone()
    };
    let (mut reader, resolution) = open_event_format(path.as_ref(), format, &opts)?;
    summarise(reader.as_mut(), format, resolution)
}

/// A summary of any recording.
#[derive(Clone, Debug, PartialEq)]
pub enum Info {
    /// A spike file.
    Spikes(SpikeInfo),
    /// An event file.
    Events(EventInfo),
}

impl fmt::Display for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Info::Spikes(s) => s.fmt(f),
            Info::Events(e) => e.fmt(f),
        }
    }
}

/// Sniffs the file at `path` ([`sniff`]) and summarises it: spike files with `spikes`, event
/// files with `events`.
pub fn info(path: impl AsRef<Path>, spikes: &PkuOptions, events: &ReadOptions) -> Result<Info> {
    let path = path.as_ref();
    match sniff(path)? {
        Format::PkuSpikes => Ok(Info::Spikes(pku::info(path, spikes)?)),
        f => Ok(Info::Events(event_info(path, f, events)?)),
    }
}
