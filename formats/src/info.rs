//! Summaries of recordings: size, duration, counts, rates, first and last timestamps.

use std::fmt;
use std::path::{Path, PathBuf};

use neuspike_schemas::EventBatch;

use crate::aedat4::{Aedat4Frames, FrameFormat};
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
    /// The APS frames beside the events (AEDAT 4 from a DAVIS), when the file has any.
    pub aps: Option<ApsInfo>,
}

/// A summary of a recording's APS frames.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ApsInfo {
    /// Frames.
    pub frames: u64,
    /// The first frame's size and pixel format.
    pub width: u16,
    /// Rows of the first frame.
    pub height: u16,
    /// Pixel format of the first frame.
    pub format: FrameFormat,
    /// Frames of another size or format than the first.
    pub other_sizes: u64,
    /// Timestamp of the first frame, ns.
    pub first_t_ns: i64,
    /// Timestamp of the last frame, ns.
    pub last_t_ns: i64,
}

impl ApsInfo {
    /// Frames per second between the first and last frame (0 for fewer than two).
    pub fn rate_per_s(&self) -> f64 {
        let d = self.last_t_ns.saturating_sub(self.first_t_ns);
        if self.frames < 2 || d <= 0 {
            0.0
        } else {
            (self.frames - 1) as f64 * 1e9 / d as f64
        }
    }

    /// Summarises the APS frames of an AEDAT 4 file (`None` when it has none). Each frame is
    /// decoded and checked as a reader of frames would.
    ///
    /// # Errors
    /// The file cannot be read, or a frame packet is corrupt.
    pub fn of_aedat4(path: &Path) -> Result<Option<ApsInfo>> {
        let mut info: Option<ApsInfo> = None;
        for frame in Aedat4Frames::open(path)? {
            let f = frame?;
            match &mut info {
                None => {
                    info = Some(ApsInfo {
                        frames: 1,
                        width: f.width,
                        height: f.height,
                        format: f.format,
                        other_sizes: 0,
                        first_t_ns: f.t_ns,
                        last_t_ns: f.t_ns,
                    });
                }
                Some(i) => {
                    i.frames += 1;
                    i.other_sizes +=
                        u64::from((f.width, f.height, f.format) != (i.width, i.height, i.format));
                    i.last_t_ns = f.t_ns;
                }
            }
        }
        Ok(info)
    }
}

impl fmt::Display for ApsInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let format = match self.format {
            FrameFormat::Gray => "grey",
            FrameFormat::Gray16 => "16-bit grey",
            FrameFormat::Bgr => "BGR",
            FrameFormat::Bgra => "BGRA",
        };
        write!(
            f,
            "{} APS frames, {}x{} {format}, first t {} ns, last t {} ns, {:.1} frames/s",
            self.frames,
            self.width,
            self.height,
            self.first_t_ns,
            self.last_t_ns,
            self.rate_per_s()
        )?;
        if self.other_sizes > 0 {
            write!(f, " ({} of another size or format)", self.other_sizes)?;
        }
        Ok(())
    }
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
        if let Some(aps) = &self.aps {
            write!(f, "\n  {aps}")?;
        }
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
                "packets of other streams (frames, IMU, triggers) skipped by the event reader",
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
        aps: None,
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
    let mut info = summarise(reader.as_mut(), format, resolution)?;
    if format == Format::Aedat4 && info.stats.skipped_packets > 0 {
        info.aps = ApsInfo::of_aedat4(path.as_ref())?;
    }
    Ok(info)
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
